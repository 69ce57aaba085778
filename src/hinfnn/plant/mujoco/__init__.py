"""MuJoCo as the true plant (optional extra ``hinfnn[mujoco]``; docs/mujoco.md).

The controller is designed from the paper's closed-form model; here the truth is a different
physics engine: MuJoCo's recursive rigid-body dynamics, its collision detection and its soft
constraint solver, stepped in discrete time. MuJoCo is driven through the sampled-data path: at
each control instant the controller computes τ from a :class:`~hinfnn.Measurement`, τ is held
(zero-order hold) while MuJoCo advances by the control period in whole MuJoCo timesteps.

* :mod:`.scene` — the MuJoCo model of a true plant: hinfnn's arms as MJCF (:func:`chain_xml`,
  :func:`two_link_xml`) or a user's MJCF, the true surface as a geom, the contact calibrated to
  k (N/m) and c (N·s/m) (:func:`contact_solref`), MuJoCo's Coulomb friction, a contact sensor;
* :mod:`.engine` — :class:`MujocoPlant` (the plant protocol, one host call per control period for
  a whole batch, MuJoCo's thread pool inside it) and :class:`MujocoState`.

``import hinfnn`` (and this package) never imports ``mujoco``: it is imported on first use, and a
missing package raises :class:`~hinfnn.errors.ConfigError` (key ``plant.engine``).
"""

from .engine import CALLBACKS, CartesianSensing, LineSensing, MujocoPlant, MujocoState
from .scene import (CYLINDER_HALF_LENGTH, FRICTION_DAMPING, IMPEDANCE, IMPRATIO, INTEGRATORS,
                    POINT_MASS_GYRATION_RADIUS, SUPPORTED_SURFACES, TIP_RADIUS, Scene, build_scene, chain_from_model,
                    chain_urdf, chain_xml, contact_solref, friction_solref, mjcf_two_link, require_mujoco,
                    surface_geom, two_link_xml)

__all__ = ["MujocoPlant", "MujocoState", "LineSensing", "CartesianSensing", "Scene", "build_scene", "chain_xml",
           "two_link_xml", "chain_from_model", "chain_urdf", "mjcf_two_link", "contact_solref", "friction_solref",
           "surface_geom", "require_mujoco", "INTEGRATORS", "CALLBACKS", "IMPEDANCE", "IMPRATIO", "FRICTION_DAMPING",
           "POINT_MASS_GYRATION_RADIUS", "TIP_RADIUS", "CYLINDER_HALF_LENGTH", "SUPPORTED_SURFACES"]
