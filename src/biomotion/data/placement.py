"""Put every cached clip in one frame: generic body size, on the floor, overground, starting at the origin.

Sources differ in ways that are not motion: labs put the floor at different heights (the Fukuchi treadmill belt is
about 10 cm above its lab origin), treadmill runs stay in place while the belt carries the stance foot backwards,
clips start anywhere in the room, and pelvis translations grow with the subject's size. A generator trained on the
raw mixture would have to learn all of that as noise. Each clip's pelvis translations (only those; rotations are
untouched) are therefore:

1. made overground for treadmill clips: the belt speed times time is added along +x (the walking direction of
   the Fukuchi and Hamner labs: without it the stance foot moves at minus the belt speed, measured in
   ``tests/data/test_placement.py``), so the stance foot rests on the floor as it does overground;
2. scaled to the generic body: x (GENERIC_HEIGHT / height) when the subject's height is known (the Rajagopal 2016
   model represents a 1.70 m adult, Rajagopal et al. 2016 Sec. II), so the generator scales them back for a
   person. The belt is added first, so it is scaled with the legs that run on it: added after, a 1.81 m runner's
   planted foot would slide at 6 % of the belt speed;
3. started at the origin: pelvis_tx and pelvis_tz of the first frame are 0;
4. put on the floor: pelvis_ty is lowered so the 5th percentile over frames of the lowest foot contact point
   (`biomotion.body.contact.foot_points` on the canonical model) is at y = 0, the absolute ground the contact
   metrics use (PG-BIG Sec. 4.2).
"""

from __future__ import annotations

import numpy as np

from biomotion.body.contact import GROUND_PERCENTILE, lowest_foot_heights
from biomotion.motion import Motion

GENERIC_HEIGHT = 1.70  # m, the adult the Rajagopal 2016 model represents


def place_clip(motion: Motion, model, *, height: float | None, treadmill_speed: float | None) -> Motion:
    """The clip with its pelvis translations placed as the module docstring says (canonical coordinates)."""
    names = motion.names
    if not all(n in names for n in ("pelvis_tx", "pelvis_ty", "pelvis_tz")):
        return motion
    values = motion.values.astype(np.float64, copy=True)
    tx, ty, tz = (names.index(n) for n in ("pelvis_tx", "pelvis_ty", "pelvis_tz"))
    if not motion.mask[[tx, ty, tz]].all():
        return motion
    if treadmill_speed is not None:
        values[:, tx] += treadmill_speed * (motion.times - motion.times[0])
    if height is not None:
        values[:, [tx, ty, tz]] *= GENERIC_HEIGHT / height
    values[:, [tx, tz]] -= values[:1, [tx, tz]]
    full = np.where(motion.mask[None, :], values, model.defaults.numpy()[None, :])
    values[:, ty] -= np.percentile(lowest_foot_heights(model, full), GROUND_PERCENTILE)
    return motion.with_values(values.astype(motion.values.dtype))
