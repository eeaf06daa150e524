"""Data layer: the :class:`Sequence` type, GRAB-layout I/O, splits and perturbations.

SynthGRAB (the built-in generator) lives in :mod:`grip_bench.data.synth`.
"""

from .grab_io import (
    ManoBackend,
    MANOModelBackend,
    dataset_hash,
    list_sequences,
    load_mano_backend,
    object_mesh_path,
    read_grab,
    read_grab_header,
    resolve_object_mesh,
    write_grab,
)
from .perturb import perturb_dataset, perturb_sequence
from .sequence import (
    CONTACT_HAND_LABELS,
    Sequence,
    contact_label,
    make_body_params,
    make_hand_params,
    make_rigid_params,
)
from .splits import (
    GRAB_SPLITS,
    GRIP_SPLITS,
    read_splits,
    sequences_in_split,
    split_of,
    write_splits,
)

__all__ = [
    "CONTACT_HAND_LABELS", "GRAB_SPLITS", "GRIP_SPLITS", "MANOModelBackend", "ManoBackend",
    "Sequence", "load_mano_backend",
    "contact_label", "dataset_hash", "list_sequences", "make_body_params", "make_hand_params",
    "make_rigid_params", "object_mesh_path", "perturb_dataset", "perturb_sequence",
    "read_grab", "read_grab_header", "read_splits", "resolve_object_mesh", "sequences_in_split",
    "split_of", "write_grab", "write_splits",
]
