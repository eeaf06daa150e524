"""Named tolerances, thresholds and protocol constants, kept in one place.

Units inside the suite are metres, radians, seconds, kilograms. Reports convert.
"""

# --- Frame rates -------------------------------------------------------------
GRAB_FPS = 120.0  # GRAB motion capture rate
NPZ_MAX_MEMBER_BYTES = 4 << 30  # an .npz member larger than this (unpacked) is refused:
# GRAB's largest arrays are a few MB; a tiny zip can claim terabytes (a zip bomb)
FPS = 30.0  # the suite's working rate (GRAB subsampled by 4)
MAX_SOURCE_FPS = 1000.0  # a capture rate above this is a corrupt header (GRAB: 120 fps)

# --- Contact definitions (docs/contract.md, "Definitions") ---------------------------
CONTACT_THRESHOLD = 0.0045  # m; GRAB's contact distance, defines grasp frames
CC_THRESHOLD = 0.002  # m; GRIP code's contact-consistency vertex selection
# Held frames (metrics.contact.held_mask): where the paper means "grasp frames"
HELD_TOUCH = 0.002  # m; the GT thumb and another finger this close: the hand grips
HELD_MIN_LIFT = 0.005  # m; the object's lowest point this far above rest: nothing else holds it
HELD_TRIM = 5  # frames dropped at each end of a hold (the grasp forming or letting go)

# --- Sensors (GRIP Sec. 3.2-3.4) --------------------------------------------
AMBIENT_N_POINTS = 1024
AMBIENT_RADIUS = 0.2  # m, hemisphere radius
AMBIENT_DECAY = 5.0  # feature exp(-5 d)
PROXIMITY_N_VERTS = 99
PROXIMITY_DECAY = 50.0  # feature exp(-50 d)
FUTURE_FRAMES = 10
# grip-blind's object input (sensors.object_pose_feature), per hand: the object frame's
# origin in the wrist frame (3, m) and the object's rotation in the wrist frame (6D)
OBJECT_POSE_DIM = 3 + 6

# --- Hand anatomy ------------------------------------------------------------
HAND_LENGTH = 0.19  # m, default adult hand length (wrist crease to middle tip)

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

# --- World frame --------------------------------------------------------------
UP = (0.0, 1.0, 0.0)  # SynthGRAB / procedural body: y up, body faces +z

# --- geometry ---
# Rotation series switch: below this angle (rad) sin(t)/t and friends use a Taylor series
# in t^2 (truncation error < 1e-16 here), keeping values and gradients smooth at 0 in
# float32 too, where ROT_EPS = 1e-6 would leave cancellation in the autograd formula.
ROT_SERIES_ANGLE = 1e-2
MAX_HOLE_FRACTION = (
    0.15  # holes with perimeter up to this share of the bbox diagonal get fan-closed
)
FLAT_TOL = 1e-6  # relative; thinnest/largest vertex spread (and volume/extent^3) below = flat
SDF_EXACT_DEPTH = 0.02  # m; the grid holds exact node values within this distance of the surface
SDF_COARSE_FACTOR = 4  # coarse grid (fills nodes beyond SDF_EXACT_DEPTH) = this x the spacing
SDF_BARY_TOL = 1e-7  # barycentric coordinate below which a closest point sits on an edge/vertex
# m; cells whose estimated trilinear error (spacing * gradient spread / 4) exceeds this use the
# exact path
SDF_KINK_TOL = 0.25e-3

# --- grip nets ---------------------------------------------------------------
# Paper-scale sizes of GRIP's networks (docs/contract.md, "Definitions"; GRIP Sec. 3.4-3.6).
GRIP_HIDDEN = 2048  # inner width of a residual block
GRIP_WIDTH = 1024  # width between residual blocks
GRIP_LATENT = 256  # CNet / ANet latent code per frame
GRIP_DROPOUT = 0.3
GRIP_LEAKY_SLOPE = 0.2
ROT6D_DIM = 6
N_HAND_POSE_JOINTS = 15  # MANO finger joints (wrist excluded)
N_ARM_JOINTS = 4  # left/right shoulder and elbow
ANET_NOISY_FUTURE = 5  # noisy future arm frames fed to ANet (GRIP Sup. Mat. 7)
# CNet per-frame body context: 21 SMPL-X body joints x 6D (no root) + 2 wrists x
# (6D orientation + 3D position) + 10 shape coefficients.
CNET_BODY_DIM = 21 * 6 + 2 * 9 + 10

# --- data ---
# Plausibility bounds that catch unit mistakes in data files (InputError, not clipping).
MAX_ABS_TRANSL = 10.0  # m; larger translations look like millimetres
MAX_AXIS_ANGLE = 12.6  # rad (~4 pi); larger rotation vectors look like degrees
SUBJECT_HEIGHT_RANGE = (0.5, 2.6)  # m; outside looks like centimetres or a typo
HAND_SCALE_RANGE = (0.3, 3.0)  # multiplier of HAND_LENGTH
N_HAND_POSE = 45  # full MANO finger pose, 15 joints x axis-angle
# TOCH protocol (GRAB-T, GRAB-R) and GRIP's ANet arm noise, per frame, i.i.d. Gaussian.
TOCH_T_SIGMAS = (0.01, 0.02)  # m, hand translation
TOCH_R_SIGMAS = (0.3, 0.5)  # rad, each hand-joint axis-angle component
ANET_SHOULDER_SIGMA = 0.01  # rad
ANET_ELBOW_SIGMA = 0.03  # rad
# ANet's second training noise: the wrist translation noise of GRAB-T's larger level, mapped
# to the arms by IK (the perturbation family the TOCH-style refiner also trains on).
ANET_WRIST_SIGMA = 0.02  # m, per axis and frame
ANET_NOISE_SCALE = (0.0, 1.25)  # per-sample scale of either training noise (0: clean input too)
ANET_WRIST_SHARE = 0.5  # share of ANet's training samples that carry the wrist noise

# --- body ---
BODY_HEIGHT = 1.7  # m, default stature of the procedural body
ELBOW_MAX_FLEXION = 2.6  # rad (~150 deg), the anatomical flexion range the arm IK allows
ARM_IK_TOL = 1e-6  # m; a wrist target within this of the reachable shell counts as reached

# --- metrics ---
# Intersection volume
IV_GRID_PITCH = 0.001  # m; naive containment-grid reference used by tests and benchmarks
# Physics stability (grip_bench.metrics.physics); the paper's protocol constants are above.
SIM_FRICTION = 1.0  # sliding; skin on plastic / wood is about 0.6-1.0, Bullet grasp tests use ~1
SIM_TORSIONAL_FRICTION = 0.005  # m; MuJoCo default: a finger pad a few mm wide resists twisting
SIM_ROLLING_FRICTION = 0.0001  # m; MuJoCo default
SIM_CONDIM = 4  # normal + 2 tangential + torsional: a two-finger pinch does not let the object spin
SIM_SOLREF = (0.01, 1.0)  # s, damping ratio; 10 ms >= 2 SIM_DT (stable), critically damped, stiffer
# than MuJoCo's 20 ms so a resting object sinks ~0.1 mm rather than ~0.5 mm
SIM_SOLIMP = (0.95, 0.99, 0.001, 0.5, 2.0)  # impedance ramps to 0.99 within 1 mm of penetration
SIM_IMPRATIO = 10.0  # elliptic cones: friction stiffer than normal force, less creep in a hold
SIM_MAX_SPEED = 50.0  # m/s; 1 s of free fall reaches 9.8 m/s, anything far beyond has diverged
SIM_DISP_CAP = 0.1  # m; a diverged run enters displacement means as this, never dropped
SIM_HAND_PIECE_POINTS = 120  # vertices per convex hand piece (bones are split into clusters)
SIM_CONTACT_MARGIN = (
    0.001  # m; skin compliance: contacts act within 1 mm (see physics._contact_params)
)
SIM_MIN_PIECE_VOLUME = (
    1e-10  # m^3 (0.1 mm^3); flatter convex pieces are dropped (MuJoCo rejects them)
)
SIM_CONVEX_TOL = 0.01  # a mesh within 1% of its hull volume is used as one convex piece
SIM_COACD_THRESHOLD = 0.05  # CoACD concavity; 0.1 leaves a bowl's pieces 40% overfull
SIM_COACD_MAX_HULLS = -1  # no cap: the threshold decides
SIM_COACD_RESOLUTION = 1000  # CoACD sampling resolution (default 2000); halves run time
SIM_COACD_MCTS_ITERATIONS = 60  # default 150
SIM_COACD_MCTS_NODES = 10  # default 20
# The hold test (grip_bench.metrics.hold; experimental, not yet in the tables): an articulated
# hand squeezes and holds. The friction, solver and cone settings are the SIM_* above.
HOLD_CONTACT_MARGIN = 0.0  # m; no skin margin: the servos close the gap, nothing pushes at t = 0
HOLD_TOUCH = 0.002  # m; finger bones this close to the object are tightened toward it
HOLD_TIGHTEN = 0.0015  # m; how far past the surface each touching bone is driven (a squeeze)
HOLD_SETTLE_SECONDS = 0.2  # s without gravity: contacts settle, a penetrating grasp explodes
HOLD_SETTLE_DAMPING = (20.0, 0.05)  # N s/m, N m s/rad on the object while settling: it creeps
# to where the contacts balance instead of keeping the momentum of the first touch
HOLD_RAMP_SECONDS = 0.1  # s; the servo targets move from the frame's pose to the tightened one
HOLD_SETTLE_FAIL = 0.005  # m; settle displacement beyond this fails the test
HOLD_DISP = 0.02  # m; success: the object moves less than this during the hold ...
HOLD_ROT = 15.0  # degrees; ... and turns less than this
HOLD_DISP_CAP = 0.1  # m; displacements (and diverged runs) enter medians capped here
HOLD_REACH = 0.02  # m; hand and object pieces farther apart than this are left out (see hold)
HOLD_FINGER_KP = 10.0  # N m / rad; finger joint position servos
HOLD_FINGER_KV = 0.3  # N m s / rad; about critical damping with the armature below
HOLD_FINGER_TORQUE = 0.3  # N m; servo torque cap: a human finger joint exerts ~1 N m at most
HOLD_BONE_MASS = 0.005  # kg per finger bone (gravity-compensated: the hand does not sag)
HOLD_CONE_EDGES = 8  # edges of the linearised friction cone (geometry.wrench, the force check)
HOLD_MAX_DEPTH = 0.005  # m; a hand whose deepest vertex is further inside is not holding (qs, sim)
HOLD_MU_SENSITIVITY = (0.5, 3.0)  # friction of the hold check's sensitivity columns (1: reported)
# Grip-strength sensitivity of the articulated hold (hold_sim_weak / hold_sim_strong): the
# finger servos' gain and torque cap scaled by these factors together (the damping by the
# root, keeping the damping ratio). x3 is 0.9 N m a joint, near a human finger's ~1 N m at
# most; x1/3 a light touch. The servo model is a free parameter, so the verdict's dependence
# on it is reported, not tuned (docs/physics_hold.md, s52).
HOLD_GRIP_SENSITIVITY = (1.0 / 3.0, 3.0)
# The wedge rule (metrics.hold.inward_force): settled contacts pushing the hands *into* the
# object with more than this many object weights mean a finger wedged inside a thin wall,
# glued by the two faces' opposing forces, not a grasp. SynthGRAB 2.4's ground truth: 8,400-
# 22,200 weights on wedged frames, at most 8.3 on every other (docs/physics_hold.md, s49).
HOLD_WEDGE_WEIGHTS = 50.0
HOLD_ARMATURE = 2e-3  # kg m^2; reflected inertia of a finger joint: servo period ~90 ms >> SIM_DT
SIM_FREE_FALL_5 = 0.5 * GRAVITY * SIM_DT**2 * SIM_PAPER_STEPS * (SIM_PAPER_STEPS + 1)
# m (2.55 mm): free fall over the support test's 5 semi-implicit Euler steps, printed beside it

# Collision pieces (grip_bench.geometry.pieces): outward error measured and bounded.
PIECE_MAX_ERROR = 0.0005  # m; a piece's hull may stick out at most this far past the surface
PIECE_DEPTH = 0.003  # m; inner layer of a surface patch's prism (halved at thin walls)
PIECE_HAND_DEPTH = 0.002  # m; the same for hand bones (fingers are >= 6 mm thick)
PIECE_MIN_DEPTH = 0.00025  # m; thinner prisms collide unreliably (MuJoCo's margin is 1 mm)
PIECE_PATCH_FACES = 64  # faces per patch before error-driven splits (~1 cm^2 on SynthGRAB)

# --- synth objects ---------------------------------------------------------------
SYNTH_OBJ_SEGMENTS = 40  # circular segments for hand-sized parts (~0.3% cylinder volume loss)
SYNTH_OBJ_SEGMENTS_LARGE = 48  # spheres, tori and large vessels
SYNTH_OBJ_SEGMENTS_SMALL = 12  # stems, buttons, handle tubes, rim rounds
SYNTH_LARGE_EXTENT = (0.30, 0.50)  # m; largest extent of two-handed SynthGRAB objects

# --- bench ---
# Stratified bootstrap over sequences (grip_bench.results.stats), rliable-style percentile CI.
BOOTSTRAP_N = 2000  # resamples; Monte-Carlo error of a 95% bound is ~1% of the CI width
BOOTSTRAP_ALPHA = 0.05  # 95% intervals
BOOTSTRAP_SEED = 0
BOOTSTRAP_CHUNK = 4_000_000  # indices drawn per vectorised chunk (~32 MB of int64); bounds
# memory only: the draws are the same for any chunk size
CACHE_SCHEMA_VERSION = 1  # bump when the cache layout or a unit's content format changes
REPORT_DECIMALS = 2  # digits after the point in rendered tables (GRIP's tables use 2)

# --- baselines ---
# GrabNet (GRAB Sec. 4, Sup. Mat. S.9): BPS object code, CoarseNet cVAE, RefineNet.
BPS_N_POINTS = 4096  # basis points
BPS_RADIUS = 0.15  # m, ball around the object centre holding the basis points
BPS_SEED = 0  # the one fixed basis shared by training and inference
GRABNET_WIDTH = 512
GRABNET_LATENT = 16
GRABNET_REFINE_ITERS = 3
# RefineNet training noise on GT grasps, as variances (GRAB S.9.2): finger joints (rad^2),
# root orientation (rad^2), translation (m^2).
GRABNET_NOISE_VAR = (0.2, 0.004, 0.05)
# TOCH-style refiner: object-centric correspondence field over temporal windows.
TOCH_MAX_DIST = 0.1  # m, rays from object points farther than this from the hand miss
TOCH_N_POINTS = 2000  # object surface samples per frame
TOCH_WINDOW = 30  # frames per temporal window
# ManipNet-style single-hand (right) autoregressive finger model.
MANIPNET_PAST = 10  # wrist frames before the current one
MANIPNET_FUTURE = 10  # wrist frames after the current one
MANIPNET_VOXEL_RES = 8  # cells per side of the wrist-frame occupancy grid
MANIPNET_VOXEL_CELL = 0.02  # m, cell size (an 8 x 2 cm = 16 cm cube)
# Grid centre in the right wrist frame: half a hand towards the fingers (-x) and a little
# to the palm side (-y), so the cube holds what the fingers can reach, not the forearm.
MANIPNET_VOXEL_CENTER = (-0.07, -0.03, 0.0)
MANIPNET_DIST_CLIP = 0.1  # m; signed distances are clipped to +-this before the network

# --- grip pipeline ---
ANET_CHUNK = 16  # offline ANet: output frames per piece of the recursion (grip.pipeline)
ANET_WARMUP = 8  # frames each piece starts early, so its start is forgotten by its first output
AMBIENT_SEED = 0  # the one fixed hemisphere sample shared by training and inference
AMBIENT_MIDDLE_JOINT = 4  # MANO middle1: the hemisphere's centre on the relaxed mean hand
VOXEL_CELLS = (
    13,
    6,
    13,
)  # voxel ambient grid (x, palm-normal, z) over the hemisphere's box: 1014 cells
INTERACTION_DISTANCE = 0.02  # m; RNet refines frames whose hand is within this of the object

# --- evaluate ---
# grip_bench.metrics.evaluate: per-sequence aggregation of the metric functions.
EVAL_MAX_PHYSICS_FRAMES = 8  # MuJoCo tests per sequence and hand (evenly spaced grasp frames);
# each costs ~30-50 ms (paper protocol) plus a 1 s hold, so all grasp frames would dominate the run
VALIDITY_NEAR = 0.02  # m; push / pull degradations act on frames with the hand this close
VALIDITY_CONTACT = 0.005  # m; vertices this close set the push / pull direction (mean normal)
EVAL_EXACT_BAND = 0.005  # m; grid distances below this (contact, CC, penetration) are recomputed
# exactly, so every threshold decision (4.5 mm, 2 mm, inside) is made on exact distances
EVAL_MAX_LISTED = 5  # missing / extra sequences named in a mismatch error (then a count)

# --- distance far field ---------------------------------------------------------
# (spacing, padding) m of the exact-valued grids that answer far="coarse" queries beyond the
# fine grid, in turn: trilinear error <~ spacing^2 / (4 * distance) (0.2 mm at 3 cm in the
# first, 1 mm at 10 cm in the second) except across an outer medial axis (~spacing / 4).
# The proximity sensor (exp(-50 d)) and its mean distance (the future cue) read them.
SDF_FAR_TIERS = ((0.006, 0.1), (0.025, 0.7))

# --- run ---
# grip-bench run (grip_bench.bench.runner); profiles' [run] sections override these.
RUN_DEFAULT_OUT = "runs"  # OUT defaults to runs/<profile>
RUN_FIGURE_METHODS = ("grip",)  # methods drawn beside ground truth in contact heatmaps

# --- baselines methods ---
# grabnet-smplx: BPS basis centre in the right wrist frame, where the fingers reach
# (half a hand towards the fingers, -x, and a little to the palm side, -y).
GRABNET_SMPLX_BPS_CENTRE = (-0.07, -0.03, 0.0)
# toch: frames whose input hand comes this close to the object are refined (m); wider than
# GRIP's 2 cm because GRAB-T moves hands by up to a few centimetres.
TOCH_INTERACTION_DISTANCE = 0.03
TOCH_HIT_THRESHOLD = 0.5  # denoised hit probability above which a correspondence is fitted
# nearest-arm: frame offsets of its key window around t (30 fps: +-1/3 s), clamped at the
# sequence's ends (offline: the window reads 10 future frames, as GRIP's offline cue does)
NEAREST_ARM_OFFSETS = (-10, -5, 0, 5, 10)

# --- object mesh intake (geometry/repair.py, docs/meshes.md) ---
# A repair may move or invent surface by at most this much (two-sided distance between the
# input and the repaired surface, mm) unless --accept-repair MM says otherwise.
MESH_REPAIR_TOLERANCE_MM = 1.0
MESH_REPAIR_CELL_FRACTION = 1.0 / 3.0  # winding-number grid cell = this x the tolerance
MESH_REPAIR_MAX_NODES = 500_000  # finest grid cells near the surface (memory/time guard)
MESH_REPAIR_SAMPLES = 20_000  # surface samples per side for the repair distance
MESH_REPAIR_MIN_SHELL = 1e-3  # shells enclosing less than this share of the volume are dropped
MESH_MAX_FACES = 2_000_000  # faces a mesh file may declare (checked before it is loaded)
MESH_MAX_FILE_BYTES = 256 * 2**20  # formats with no face count in a header (GLB, glTF)
# Units check on the bounding-box diagonal: GRAB's objects are 2-40 cm across (diagonals
# ~3-70 cm); a 5x margin each way still separates metres from centimetres (x100) and mm.
MIN_OBJECT_DIAG = 0.01  # m
MAX_OBJECT_DIAG = 3.0  # m
TYPICAL_OBJECT_DIAG = 0.2  # m; the scale hint picks the unit that lands nearest this

# --- counterfactual geometry split (data/synth/counterfactual.py, metrics/sensitivity.py) ---
# A twin's object is its source instance stretched in the object frame's horizontal plane
# (x, z) about the point of the surface nearest the palm, so the palm keeps its contact and
# the object keeps standing on the table; (name, x factor, z factor), tried in a seeded order.
CF_VARIANTS = (
    ("smaller", 0.8, 0.8), ("larger", 1.25, 1.25),
    ("narrower_x", 0.8, 1.0), ("wider_x", 1.25, 1.0),
    ("narrower_z", 1.0, 0.8), ("wider_z", 1.0, 1.25),
)
CF_INTENTS = ("lift", "pass", "use")  # one-hand intents: one grasp, one palm to keep in place
CF_TWIN_TRIES = 3  # variants tried per source episode before it yields no pair
CF_MIN_CHANGE = 0.002  # m; the closed hand must move some vertex this far, else no pair
CF_SPLIT = "counterfactual"  # the split label of the pairs (pairs.json, the table)
# metrics/sensitivity.py: the GT change (RMS over held frames and vertices) below which the
# share of the change reproduced is not defined (NaN)
CF_MIN_GT_RMS = 1e-4  # m
