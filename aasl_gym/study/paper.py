"""The reference paper's ablation studies (issue 14): the variants of a scenario's world and filter each
one runs, its trials as jobs, and the paper's metrics over them.

A trial is one episode of the helix patrol with the LC-MAP tracker, the filter's motion model matched to
the source's. Every variant runs the same seeds, so variants are compared on the same sources and noise.
A trial *diverges* when its RMSE (over the steps with an estimate) exceeds :data:`DIVERGENCE_RMSE`, the
paper's 30 m, or it never had an estimate; RMSE, final and maximum error are then averaged over the
trials that did not (mean and sample sd), as the paper reports them.

- ``multipath`` (paper: 100 trials, 20 m of water, -0.9 / 0.3): the filters ``none``, ``linear`` and
  ``phasor`` in the paper's world (RD from its first-order model) and in the exact tone world.
- ``coefficients`` (paper: 10 trials per pair): a grid of a_surf in [-1, 0] and a_bed in [0, 1], the
  direct-path filter against the one matched to the world, in both worlds.
- ``navigation`` (paper: 10 trials per level): sigma_rov from 0 to 0.7 m (velocity sd 0.4 sigma_rov), the
  filter told R_ac only against R_eff, in the Monte Carlo world; optionally with a slow drift on top.
- ``lake`` (issue 15; the paper's field trial): the nominal filter (direct path, R_ac only) against the
  compensated one (the world's multipath model, R_eff), each with the circle, square and lawnmower patrols
  of the surface vessel, on static, straight (cv), arc (ctrv) and U-shaped (uturn) source paths.
- ``arrays`` (issue 15): the scenario itself; :mod:`aasl_gym.study.array_comparison` adds the fixed arrays.
- ``facility`` (issue 15; the paper's 8-pod run): ``AASL-Facility-v0``'s own patrol, the tracker paired with
  the pod that hears the source loudest (the paper's set-up), and also with every other pod that hears it as
  an extra pair (``facility.pairs: all``), on static, cv and ctrv sources.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from aasl_gym.config import EnvConfig, merge, to_dict
from aasl_gym.measurement_models import Propagation, multipath_measurement
from aasl_gym.motion import sample_source, source_region
from aasl_gym.patrols import PatrolGeometry, helix_reference
from aasl_gym.scenarios import scenario_config
from aasl_gym.study.jobs import FACILITY_PATROL, MATCHED_FILTER, Job
from aasl_gym.study.log import Row
from aasl_gym.study.stats import mean_sd

DIVERGENCE_RMSE = 30.0  # m: a trial whose RMSE exceeds it diverged (the paper's definition)
WORLD_MODELS = ("linear", "phasor")  # how the world's reflections shape RD: the paper's first order, the exact tone
MULTIPATH_FILTERS = ("none", "linear", "phasor")
NAVIGATION_LEVELS = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7)  # m, sigma_rov
PATROL = "helix"
# The world each study runs in (model-error: the one whose models it compares).
STUDY_SCENARIOS = {
    "multipath": "shallow-water",
    "coefficients": "shallow-water",
    "navigation": "paper-monte-carlo",
    "model-error": "shallow-water",
    "arrays": "paper-monte-carlo",
    "lake": "lake",
    "facility": "facility",
}
FACILITY_MOTIONS = ("static", "cv", "ctrv")
LAKE_PATROLS = ("circle", "square", "lawnmower")
LAKE_MOTIONS = ("static", "cv", "ctrv", "uturn")  # the paper's static, straight, arc and U-shaped paths
# The lake's two filters: the paper's nominal one and its compensated one.
LAKE_FILTERS = {
    "nominal": {"multipath": "none", "compensate_navigation": False},
    "compensated": {"multipath": "matched", "compensate_navigation": True},
}


@dataclass(frozen=True)
class Variant:
    """One cell of a study: its name, its coordinates (``labels``, e.g. ``{"world": "linear"}``) and the
    config fields it changes in the study's scenario."""

    name: str
    labels: dict[str, Any]
    changes: dict[str, Any] = field(default_factory=dict)
    policy: str = PATROL  # the scripted patrol its trials fly
    record: bool = False  # keep the paths of its first seed's trials for the trajectory plots


@dataclass(frozen=True)
class Study:
    """What one study runs: ``variants`` of ``scenario`` with the user's ``changes`` under each variant's
    own, ``trials`` seeds each (the paper's count by default)."""

    name: str
    scenario: str
    trials: int
    variants: tuple[Variant, ...]
    changes: dict[str, Any] = field(default_factory=dict)
    motions: tuple[str, ...] = ()  # the source motions every variant runs (none: the one the command names)

    def config(self, variant: Variant | None = None) -> EnvConfig:
        """The config a variant's trials run with (without one: the study's base)."""
        return scenario_config(self.scenario, merge(self.changes, variant.changes if variant else {}))


def multipath_variants() -> tuple[Variant, ...]:
    """Each world model x each filter model."""
    return tuple(
        Variant(
            f"{world} world, {model} filter",
            {"world": world, "filter": model},
            {"world": {"reflection_model": world}, "filter": {"multipath": model}},
        )
        for world in WORLD_MODELS
        for model in MULTIPATH_FILTERS
    )


def coefficient_variants(size: int = 6) -> tuple[Variant, ...]:
    """A ``size`` x ``size`` grid of (a_surf in [-1, 0], a_bed in [0, 1]), each world, the direct-path
    filter and the world's own (``matched``)."""
    surface = [round(float(a), 4) for a in np.linspace(-1.0, 0.0, size)]
    bed = [round(float(a), 4) for a in np.linspace(0.0, 1.0, size)]
    return tuple(
        Variant(
            f"{world} world, {model} filter, a_surf {a_surf:+g}, a_bed {a_bed:g}",
            {"world": world, "filter": model, "surface_reflection": a_surf, "bed_reflection": a_bed},
            {
                "world": {"reflection_model": world, "surface_reflection": a_surf, "bed_reflection": a_bed},
                "filter": {"multipath": model},
            },
        )
        for world in WORLD_MODELS
        for model in ("none", "matched")
        for a_surf in surface
        for a_bed in bed
    )


def navigation_variants(levels: tuple[float, ...] = NAVIGATION_LEVELS, drift: float = 0.0) -> tuple[Variant, ...]:
    """Each sigma_rov level (m; velocity sd 0.4 sigma_rov), the filter with R_ac only and with R_eff;
    ``drift`` (m/sqrt(s)) > 0 adds the same levels with a random-walk drift of the reported position."""
    drifts = (0.0, drift) if drift > 0 else (0.0,)
    return tuple(
        Variant(
            f"sigma_rov {level:.2f} m, {'R_eff' if compensate else 'R_ac only'}" + (f", drift {sd:g}" if sd else ""),
            {"sigma_rov": level, "compensation": "R_eff" if compensate else "R_ac only", "drift": sd},
            {
                "receiver": {"nav_position_sd": level, "nav_velocity_sd": None, "nav_drift_sd": sd},
                "filter": {"compensate_navigation": compensate},
            },
        )
        for sd in drifts
        for level in levels
        for compensate in (False, True)
    )


def lake_variants() -> tuple[Variant, ...]:
    """Each filter (nominal, compensated) x each patrol of the surface vessel; the compensated filter's
    first trials are kept for the trajectory plots."""
    return tuple(
        Variant(
            f"{name} filter, {patrol}",
            {"filter": name, "patrol": patrol},
            {"filter": fields},
            policy=patrol,
            record=name == "compensated",
        )
        for name, fields in LAKE_FILTERS.items()
        for patrol in LAKE_PATROLS
    )


# The paper's pair (the loudest pod's hydrophone with the robot's), then every pod that hears as an extra pair.
FACILITY_VARIANTS = (
    Variant("loudest pod", {"pair": "loudest pod"}, {}, FACILITY_PATROL, True),
    Variant("every pod that hears", {"pair": "every pod that hears"}, {"facility": {"pairs": "all"}}, FACILITY_PATROL),
)


def make_study(
    name: str, trials: int | None = None, grid: int = 6, drift: float = 0.0, changes: dict[str, Any] | None = None
) -> Study:
    """The study ``name`` (one of :data:`STUDY_SCENARIOS` but ``model-error``) with ``trials`` seeds per
    variant (default: the paper's; arrays 100, lake and facility 20), a ``grid`` x ``grid``
    coefficient grid, an optional drift and config ``changes`` (nested plain values) to its scenario, under
    its variants' own."""
    changes = changes or {}
    variants = {
        "multipath": lambda: (trials or 100, multipath_variants()),
        "coefficients": lambda: (trials or 10, coefficient_variants(grid)),
        "navigation": lambda: (trials or 10, navigation_variants(drift=drift)),
        "arrays": lambda: (trials or 100, (Variant("arrays", {}),)),  # the scenario itself; the arrays ride along
        "lake": lambda: (trials or 20, lake_variants()),
        "facility": lambda: (trials or 20, FACILITY_VARIANTS),
    }
    if name not in variants:
        raise ValueError(f"unknown study {name!r}; allowed: {sorted(variants)}")
    count, cells = variants[name]()
    motions = {"lake": LAKE_MOTIONS, "facility": FACILITY_MOTIONS}.get(name, ())
    return Study(name, STUDY_SCENARIOS[name], count, cells, changes, motions)


def study_jobs(study: Study, motion: str, first_seed: int) -> list[Job]:
    """One job per motion (the study's, or ``motion``), variant and seed (seeds ``first_seed`` onward, the
    same for every variant)."""
    jobs = []
    for source_motion in study.motions or (motion,):
        for variant in study.variants:
            config = study.config(variant)
            data = to_dict(config)
            mode, filter_model = config.measurement.mode, MATCHED_FILTER[source_motion]
            for seed in range(first_seed, first_seed + study.trials):
                record = variant.record and seed == first_seed
                job = Job(variant.policy, "lcmap", source_motion, mode, seed, data, filter_model, record, variant.name)
                jobs.append(job)
    return jobs


def study_header(study: Study, motion: str) -> dict[str, Any]:
    """What the resume log holds a study to: its scenario's config, its variants and the source's motion."""
    base = to_dict(study.config())
    variants = [variant.changes for variant in study.variants]
    motion_field = list(study.motions) if study.motions else motion
    return {"study": study.name, "scenario": study.scenario, "motion": motion_field, "base": base, "variants": variants}


def converged(row: Row) -> bool:
    """The paper's test: the trial's RMSE is known and at most :data:`DIVERGENCE_RMSE`."""
    return row["rmse"] is not None and row["rmse"] <= DIVERGENCE_RMSE


def summarize_variants(study: Study, rows: list[Row]) -> list[Row]:
    """Per variant (and per motion, for a study of several), in the study's order: its labels, n, the
    converged share; RMSE, final and maximum error and the RMSE over the episode's second half, over the
    converged trials (mean and sd); our success share at 1 m, the median RMSE of all (a trial without an
    estimate counts as infinite) and the mean RMSE of those with one (the heat maps' and the sweep's
    measure: diverged trials included; ``no_estimate`` counts the trials left out of it, whose filter
    never started)."""
    summary = []
    for motion in study.motions or (None,):
        for variant in study.variants:
            trials = [
                row for row in rows if row["variant"] == variant.name and (motion is None or row["motion"] == motion)
            ]
            entry: Row = {"variant": variant.name, **variant.labels} | ({"motion": motion} if motion else {})
            summary.append(entry | _trial_statistics(trials))
    return summary


def _trial_statistics(trials: list[Row]) -> Row:
    kept = [row for row in trials if converged(row)]
    entry: Row = {"n": len(trials), "converged_rate": len(kept) / len(trials) if trials else None}
    for metric in ("rmse", "final_error", "max_error", "rmse_second_half"):
        entry[f"{metric}_mean"], entry[f"{metric}_sd"] = mean_sd([row[metric] for row in kept])
    entry["success_rate_1m"] = sum(row["success"]["1.0"] for row in trials) / len(trials) if trials else None
    median = float(np.median([math.inf if row["rmse"] is None else row["rmse"] for row in trials] or [math.inf]))
    entry["rmse_median"] = median if math.isfinite(median) else None
    entry["rmse_all_mean"] = mean_sd([row["rmse"] for row in trials if row["rmse"] is not None])[0]
    entry["no_estimate"] = sum(row["rmse"] is None for row in trials)
    return entry


def wrapped(values: np.ndarray, period: float) -> np.ndarray:
    """``values`` (m) folded into [-period / 2, period / 2): a tone's RD is known only modulo its wavelength."""
    return (np.asarray(values) + 0.5 * period) % period - 0.5 * period


def model_error(
    config: EnvConfig, sources, velocities, receivers, receiver_velocities, model: str = "linear"
) -> np.ndarray:
    """[RD, RRD] of a filter's multipath ``model`` (``linear``, the paper's first order, or ``none``) minus
    the exact tone's (``phasor``), shape (..., 2) (m, m/s), for sources and mobile receivers (..., 3) and
    the world's fixed hydrophone; the RD error is folded into one wavelength, what a tone tracker can tell
    apart (its whole-period offset is a state of the filter)."""
    propagation = Propagation.from_config(config.world, config.source.frequency)
    fixed = np.asarray(config.world.fixed_position, dtype=float)
    states = (sources, velocities, receivers, receiver_velocities, fixed)
    error = multipath_measurement(model, propagation, *states) - multipath_measurement("phasor", propagation, *states)
    error[..., 0] = wrapped(error[..., 0], config.wavelength)
    return error


def model_error_samples(config: EnvConfig, count: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """The errors (``count``, 2) of the ``linear`` and the direct-path (``none``) model where a study meets
    them: CV sources drawn as the env draws them, the mobile hydrophone at a uniformly random time of the
    helix patrol, with their velocities."""
    geometry = PatrolGeometry.from_config(config)
    sources, velocities, receivers, receiver_velocities = (np.zeros((count, 3)) for _ in range(4))
    for i in range(count):
        source = sample_source(rng, "cv", config.source, config.world)
        sources[i], velocities[i] = source.position, source.velocity
        receivers[i], receiver_velocities[i] = helix_reference(
            rng.uniform(0.0, config.episode.duration), config.patrol, geometry
        )
    states = (sources, velocities, receivers, receiver_velocities)
    return {model: model_error(config, *states, model=model) for model in ("linear", "none")}


def model_error_map(config: EnvConfig, spacing: float = 0.25) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ``linear`` model's RD error (m) over the vertical plane y = 0 through the pod, for still sources
    within ``source.initial_radius`` of ``source.initial_centre`` horizontally, in the water the source may
    be in, heard from the patrol's start (its velocity that of the helix there): cell centres x (m), z (m,
    top first) and the error (z, x)."""
    region = source_region(config.world, config.source)
    radius, centre = config.source.initial_radius, config.source.initial_centre[0]
    # Cell centres, half a cell off the patrol's start and the hydrophones, where the models are singular.
    xs = np.arange(centre - radius + 0.5 * spacing, centre + radius, spacing)
    zs = np.arange(region.z_max - 0.5 * spacing, region.z_min, -spacing)
    grid_x, grid_z = np.meshgrid(xs, zs)
    sources = np.stack([grid_x, np.zeros_like(grid_x), grid_z], axis=-1)
    receiver, receiver_velocity = helix_reference(0.0, config.patrol, PatrolGeometry.from_config(config))
    error = model_error(config, sources, np.zeros_like(sources), receiver, receiver_velocity)
    return xs, zs, error[..., 0]
