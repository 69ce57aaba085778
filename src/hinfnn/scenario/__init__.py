"""Scenarios: typed configuration (the section dataclasses are the schema), registries of arms,
surfaces and plants, the shipped TOML files, a scenario's objects built once (:class:`Setup`) and
the runs it describes."""

from . import sections as _sections  # noqa: F401  (registers the shipped kinds)
from .core import Scenario, keys, load_scenario, parse_override, scenario_names, schema_table
from .registry import ARMS, PLANTS, SURFACES
from .schema import Matrix, Registry, param, section
from .setup import Setup, describe
from .sections import (ArmConfig, ContactConfig, ControllerConfig, DisturbanceConfig, PlantConfig, ReferenceConfig,
                       SimulationConfig, SurfaceConfig)

__all__ = ["Scenario", "Setup", "describe", "load_scenario", "scenario_names", "parse_override", "keys", "schema_table",
           "ARMS", "SURFACES", "PLANTS", "Registry", "section", "param", "Matrix",
           "ArmConfig", "SurfaceConfig", "PlantConfig", "ContactConfig", "DisturbanceConfig", "ControllerConfig",
           "ReferenceConfig", "SimulationConfig"]
