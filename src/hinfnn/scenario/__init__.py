"""Scenarios: typed configuration (the section dataclasses are the schema), registries of arms,
surfaces and plants, the shipped TOML files, and the runs a scenario describes."""

from . import sections as _sections  # noqa: F401  (registers the shipped kinds)
from .core import Scenario, keys, load_scenario, parse_override, scenario_names, schema_table
from .registry import ARMS, PLANTS, SURFACES
from .schema import Matrix, Registry, param, section
from .sections import (ArmConfig, ContactConfig, ControllerConfig, DisturbanceConfig, PlantConfig, ReferenceConfig,
                       SimulationConfig, SurfaceConfig)

__all__ = ["Scenario", "load_scenario", "scenario_names", "parse_override", "keys", "schema_table",
           "ARMS", "SURFACES", "PLANTS", "Registry", "section", "param", "Matrix",
           "ArmConfig", "SurfaceConfig", "PlantConfig", "ContactConfig", "DisturbanceConfig", "ControllerConfig",
           "ReferenceConfig", "SimulationConfig"]
