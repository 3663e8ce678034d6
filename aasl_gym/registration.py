"""All of AASL-Gym's environment ids, registered in one place (on ``import aasl_gym``)."""

from __future__ import annotations

from gymnasium.envs.registration import register, registry

from aasl_gym.config import ConfigError, EnvConfig

ENTRY_POINT = "aasl_gym.env:AASLEnv"

# id -> the patrol pattern whose command the action is added to (None: the action is the command)
ENV_IDS: dict[str, str | None] = {
    "AASL-v0": None,
    "AASL-Helix-v0": "helix",
    "AASL-Spiral-v0": "spiral",
    "AASL-Circle-v0": "circle",
    "AASL-Lawnmower-v0": "lawnmower",
    "AASL-Square-v0": "square",
    "AASL-Greedy-v0": "greedy",
}
# The multi-pod facility (aasl_gym.facility_env): its own patrol (the loop, then the spiral about a pod).
FACILITY_ID = "AASL-Facility-v0"
ALL_IDS = (*ENV_IDS, FACILITY_ID)


def register_envs() -> None:
    for env_id, patrol in ENV_IDS.items():
        if env_id not in registry:
            # The env truncates itself at episode.duration, which a config may change.
            register(id=env_id, entry_point=ENTRY_POINT, kwargs={"patrol": patrol})
    if FACILITY_ID not in registry:
        register(id=FACILITY_ID, entry_point="aasl_gym.facility_env:FacilityEnv")


def check_env_fits(env_id: str, config: EnvConfig, option: str, remedy: str = "") -> None:
    """Raise a :class:`ConfigError` naming ``option`` (what chose ``env_id``) where the env would not run ``config``
    as its author meant: ``AASL-Facility-v0`` needs a facility (``facility.pods`` > 1), and every other id flies one
    pod and ignores the facility section, so it would silently drop a facility's other pods. ``remedy`` (say, the
    option that picks the facility's env) ends the second message."""
    pods = config.facility.pods
    if env_id == FACILITY_ID and pods == 1:
        raise ConfigError(
            f"{option}: {FACILITY_ID} needs a facility (facility.pods > 1, e.g. the scenario 'facility'); "
            "this config has one pod"
        )
    if env_id != FACILITY_ID and pods > 1:
        raise ConfigError(
            f"{option}: {env_id} flies one pod and would ignore this config's facility of {pods} pods; "
            f"the facility runs on {FACILITY_ID}{remedy}"
        )
