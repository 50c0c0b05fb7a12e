"""Motion metrics at the tensor level, one module per family; definitions, units and thresholds in docs/metrics.md.

Every metric is a function of plain tensors (batched over leading dims, masks respected, differentiable where the
definition is) and a `Metric` object whose ``update()`` scores a batch per sequence and whose ``compute()`` returns
mean ± std over sequences (`MetricResult`). Each metric object describes itself: name, label, SI unit, direction
(``higher_is_better``), paper, equation and how reports print it (`biomotion.metrics.base`). Probes and diversity
score sets of motions instead. `biomotion.metrics.registry` lists the metrics the evaluation scores on sets of clips.
"""

from biomotion.metrics.base import Metric, MetricResult
from biomotion.metrics.bounds import PercentileBounds, bound_excess
from biomotion.metrics.contact import (
    Floating,
    FootContactVelocity,
    FootSliding,
    GroundPenetration,
    LowestPointSliding,
    Penetration,
    SkateRatio,
    contact_from_force,
    contact_mask,
)
from biomotion.metrics.fidelity import Diversity, Fidelity, GaussianFidelity, MotionEntropy
from biomotion.metrics.plausibility import (
    ActivationViolation,
    AngularVelocityViolation,
    ComAccelerationViolation,
    ComVelocityViolation,
    JointRangeViolation,
)
from biomotion.metrics.probes import AgeProbe, IdentityProbe
from biomotion.metrics.reconstruction import GlobalTrajectoryError, JointError, ProcrustesJointError
from biomotion.metrics.smoothness import AccelerationError, EnergyConsistency, JerkIndex, VelocityError
from biomotion.metrics.stability import BaseOfSupport, SupportDistance, ZMPInsideSupport

__all__ = [
    "Metric",
    "MetricResult",
    "PercentileBounds",
    "bound_excess",
    "Penetration",
    "Floating",
    "FootContactVelocity",
    "FootSliding",
    "GroundPenetration",
    "SkateRatio",
    "LowestPointSliding",
    "contact_mask",
    "contact_from_force",
    "JerkIndex",
    "EnergyConsistency",
    "AccelerationError",
    "VelocityError",
    "ZMPInsideSupport",
    "BaseOfSupport",
    "SupportDistance",
    "AngularVelocityViolation",
    "ComVelocityViolation",
    "ComAccelerationViolation",
    "ActivationViolation",
    "JointRangeViolation",
    "JointError",
    "ProcrustesJointError",
    "GlobalTrajectoryError",
    "Fidelity",
    "GaussianFidelity",
    "MotionEntropy",
    "Diversity",
    "IdentityProbe",
    "AgeProbe",
]
