"""Dynamics of the lattice: the implicit (IPC backward Euler with contact inside the step, Newmark,
corotational), explicit (central differences) and XPBD integrators, loads, contact, and the driver
that runs and records them."""

from .._lazy import lazy_getattr
from .rope_scene import rope_scene  # bound eagerly: it shares its module's name

_NAMES = {
    "State": ".state", "METHODS": ".driver", "make_integrator": ".driver", "simulate": ".driver",
    "record": ".driver", "Recording": ".driver",
    "Energy": ".state", "TimeIntegrator": ".base", "AssembledIntegrator": ".base",
    "critical_time_step": ".base",
    "Newmark": ".newmark", "Corotational": ".corotational",
    "CentralDifference": ".central", "XPBDIntegrator": ".xpbd_integrator",
    "Gravity": ".loads", "VertexForce": ".loads", "FacePressure": ".loads", "LoadSet": ".loads",
    "half_sine": ".loads",
    "run_simulation": ".job", "XPBDOptions": ".xpbd", "NewmarkOptions": ".newmark",
    "Contact": ".contact", "Ground": ".contact", "Sphere": ".contact", "Box": ".contact",
    "IPC": ".ipc", "BarrierContact": ".barrier", "impulse_nodes": ".loads",
    "XPBDSolver": ".xpbd", "XPBDState": ".xpbd", "simulate_xpbd": ".xpbd",
    "RopeScene": ".rope_scene",
}
__all__ = sorted([*_NAMES, "rope_scene"])
__getattr__ = lazy_getattr(__name__, _NAMES)
