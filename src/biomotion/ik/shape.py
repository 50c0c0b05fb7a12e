"""A `biomotion.body.shape.Shape` from a BVH skeleton: its segment lengths as scale factors of a generic model.

HUMOS (``humos.md``, "Method Summary") conditions motion on the body's identity; for a skeleton capture without
markers the identity is what its bones say. The factors are those the skeleton retargeting already fits
(`biomotion.ik.skeleton.segment_scales`, PG-BIG appendix A.5 step 2: per body, the median source distance between
the mapped joints that bound it over the model's distance in the default pose; the foot from the registered toe;
unbounded bodies inherit their parent's mean factor), so a clip retargeted by ``biomotion retarget`` and the Shape
of its skeleton describe the same scaled model. It lives in ``ik`` because ``body`` may not import ``ik``.
"""

from __future__ import annotations

from pathlib import Path

from biomotion.body.model import BodyModel
from biomotion.body.shape import Shape, shape_of_factors
from biomotion.ik.skeleton import JointMap, face_forward, joint_map_for, joint_positions, segment_scales
from biomotion.io.bvh import read_bvh


def shape_from_bvh(
    path: str | Path,
    generic: BodyModel,
    *,
    joint_map: JointMap | None = None,
    mass: float | None = None,
    height: float | None = None,
) -> Shape:
    """The Shape of the skeleton in the BVH file ``path`` relative to ``generic`` (module docstring).

    ``joint_map`` defaults to the built-in map that fits the skeleton's joints (`joint_map_for`). A skeleton has no
    mass: ``mass`` (kg) defaults to the generic model's, with its distribution; ``height`` (m) is kept as given.
    """
    source = joint_positions(read_bvh(path))
    joint_map = joint_map or joint_map_for(source.names)
    source = face_forward(source.select(joint_map.source_joints()), joint_map)
    factors = segment_scales(generic, source, joint_map)
    return shape_of_factors(generic, factors, mass=mass, height=height)
