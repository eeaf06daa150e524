"""Named tolerances, thresholds and protocol constants, kept in one place.

Units inside the suite are metres, radians, seconds, kilograms. Reports convert.
"""

# --- Frame rates -------------------------------------------------------------
GRAB_FPS = 120.0  # GRAB motion capture rate
FPS = 30.0  # the suite's working rate (GRAB subsampled by 4)
GRAB_SUBSAMPLE = 4

# --- Contact definitions (DESIGN 5) -----------------------------------------
CONTACT_THRESHOLD = 0.0045  # m; GRAB's contact distance, defines grasp frames
CC_THRESHOLD = 0.002  # m; GRIP code's contact-consistency vertex selection

# --- Sensors (GRIP Sec. 3.2-3.4) --------------------------------------------
AMBIENT_N_POINTS = 1024
AMBIENT_RADIUS = 0.2  # m, hemisphere radius
AMBIENT_DECAY = 5.0  # feature exp(-5 d)
PROXIMITY_N_VERTS = 99
PROXIMITY_DECAY = 50.0  # feature exp(-50 d)
FUTURE_FRAMES = 10

# --- Hand anatomy ------------------------------------------------------------
HAND_LENGTH = 0.19  # m, default adult hand length (wrist crease to middle tip)
N_HAND_JOINTS = 16  # MANO: wrist + 15 finger joints
N_HAND_KEYPOINTS = 21  # + 5 fingertips

# --- Geometry tolerances -----------------------------------------------------
MERGE_TOL = 1e-8  # m; duplicate-vertex merge distance for loaded meshes
MIN_OBJECT_EXTENT = 0.005  # m; smaller looks like a unit mistake
MAX_OBJECT_EXTENT = 2.0  # m; larger looks like millimetres
SDF_GRID_SPACING = 0.002  # m; default distance-field grid spacing
SDF_GRID_PADDING = 0.03  # m; grid margin around the object
SDF_EXACT_BAND = 0.5e-3  # m; grid/exact agreement target near the surface
DEFAULT_DENSITY = 500.0  # kg/m^3; household objects (GRAB objects are light plastic/wood)
N_SURFACE_SAMPLES = 2048

# --- Physics (GRIP supplementary Sec. 11) ------------------------------------
SIM_DT = 1.0 / 240.0
SIM_PAPER_STEPS = 5
SIM_STABLE_DISP = 0.001  # m
SIM_HOLD_SECONDS = 1.0
GRAVITY = 9.81

# --- Rotations ---------------------------------------------------------------
ROT_EPS = 1e-6  # small-angle switch for series expansions

# --- World frame --------------------------------------------------------------
UP = (0.0, 1.0, 0.0)  # SynthGRAB / procedural body: y up, body faces +z
