"""The canonical skeleton every source is mapped onto: Rajagopal 2016's 39 coordinates, in the model's order.

Rajagopal AA et al. (2016) Full-body musculoskeletal model for muscle-driven simulation of human gait,
IEEE TBME 63(10):2068-2079 (``../shared/data/opensim-models/Models/Rajagopal/Rajagopal2016.osim``).
Models of the same lineage (gait2392, Hamner 2010, LaiArnold, the Fukuchi models) name their coordinates the same
way, so sources are mapped by name; a source lacking a coordinate gets mask False for it.

Sign conventions differ for knee flexion: positive in the Rajagopal family, negative in the Fukuchi ``_simple``
models and in Hamner 2010. `KNEE_SIGN_FLIPPED` lists those sources; the registry flips them to the canonical sign.
"""

from __future__ import annotations

CANONICAL_COORDINATES: tuple[str, ...] = (
    "pelvis_tilt",
    "pelvis_list",
    "pelvis_rotation",
    "pelvis_tx",
    "pelvis_ty",
    "pelvis_tz",
    "hip_flexion_r",
    "hip_adduction_r",
    "hip_rotation_r",
    "knee_angle_r",
    "knee_angle_r_beta",
    "ankle_angle_r",
    "subtalar_angle_r",
    "mtp_angle_r",
    "hip_flexion_l",
    "hip_adduction_l",
    "hip_rotation_l",
    "knee_angle_l",
    "knee_angle_l_beta",
    "ankle_angle_l",
    "subtalar_angle_l",
    "mtp_angle_l",
    "lumbar_extension",
    "lumbar_bending",
    "lumbar_rotation",
    "arm_flex_r",
    "arm_add_r",
    "arm_rot_r",
    "elbow_flex_r",
    "pro_sup_r",
    "wrist_flex_r",
    "wrist_dev_r",
    "arm_flex_l",
    "arm_add_l",
    "arm_rot_l",
    "elbow_flex_l",
    "pro_sup_l",
    "wrist_flex_l",
    "wrist_dev_l",
)

#: The canonical model's bodies (Rajagopal 2016's BodySet, in its order): the names a control target's
#: ``joint_position`` takes (`biomotion.guidance.control`); each body's origin is its joint centre with its parent.
CANONICAL_BODIES: tuple[str, ...] = (
    "pelvis",
    "femur_r",
    "tibia_r",
    "patella_r",
    "talus_r",
    "calcn_r",
    "toes_r",
    "femur_l",
    "tibia_l",
    "patella_l",
    "talus_l",
    "calcn_l",
    "toes_l",
    "torso",
    "humerus_r",
    "ulna_r",
    "radius_r",
    "hand_r",
    "humerus_l",
    "ulna_l",
    "radius_l",
    "hand_l",
)

KNEE_COORDINATES = ("knee_angle_r", "knee_angle_l")

#: Coordinates the canonical model's coupler constraints set from another one (the patella's ``_beta`` from the
#: knee angle): they carry no information of their own. Sources disagree on them (the Schreiber-Moissenet models
#: leave ``_beta`` free, near 0.01 rad at any knee angle; most others lack it), so whatever reads a clip to tell
#: people apart must not read them.
COUPLED_COORDINATES = ("knee_angle_r_beta", "knee_angle_l_beta")

#: Default rate of the cached training set (Hz): PG-BIG and HumanML3D-style generators work at 20-30 Hz, and
#: 30 Hz keeps running kinematics (stride frequency about 1.4 Hz, content below 10 Hz) well resolved.
DEFAULT_RATE = 30.0
