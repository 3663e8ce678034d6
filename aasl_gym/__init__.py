"""AASL-Gym: observability-aware patrol of underwater infrastructure, as a Gymnasium environment.

Importing the package registers ``AASL-v0``, the patrol variants (``AASL-Helix-v0``, ...) and the
multi-pod ``AASL-Facility-v0`` (:data:`ALL_IDS`); so does ``gym.make("aasl_gym:AASL-v0")``.
"""

from aasl_gym.config import ConfigError, EnvConfig, from_dict, load_config, save_config, to_dict
from aasl_gym.env import AASLEnv
from aasl_gym.registration import ALL_IDS, ENV_IDS, FACILITY_ID, register_envs

register_envs()

__all__ = [
    "ALL_IDS",
    "ENV_IDS",
    "FACILITY_ID",
    "AASLEnv",
    "ConfigError",
    "EnvConfig",
    "from_dict",
    "load_config",
    "save_config",
    "to_dict",
]
__version__ = "0.1.0"
