"""aasl_gym.study's grid and resume log, without running an episode."""

import json

import pytest

from aasl_gym.config import EnvConfig, to_dict
from aasl_gym.study.jobs import StudyGrid, build_jobs, effective_config, episode_key
from aasl_gym.study.log import EpisodeLog, LogMismatch


def test_the_grid_runs_every_combination_on_the_same_seeds():
    grid = StudyGrid(
        ("helix", "spiral"),
        ("lcmap", "naive"),
        ("static", "ca"),
        episodes=3,
        first_seed=50,
        reflections=False,
        multipath="none",
        filter_model="matched",
        trajectories=2,
    )
    config = EnvConfig()
    jobs = build_jobs(grid, config)
    assert len(jobs) == 2 * 2 * 2 * 3
    assert [(j.motion, j.policy, j.initializer, j.seed) for j in jobs[:4]] == [
        ("static", "helix", "lcmap", 50),
        ("static", "helix", "lcmap", 51),
        ("static", "helix", "lcmap", 52),
        ("static", "helix", "naive", 50),
    ]
    for policy in grid.policies:
        for initializer in grid.initializers:
            seeds = sorted(j.seed for j in jobs if (j.policy, j.initializer) == (policy, initializer))
            assert seeds == [50, 50, 51, 51, 52, 52]  # each seed once per motion
    assert {(j.motion, j.filter_model) for j in jobs} == {("static", "cv"), ("ca", "ca")}
    # The first initializer's first two seeds are recorded for the trajectory plots, nothing else.
    assert {(j.initializer, j.seed) for j in jobs if j.record} == {("lcmap", 50), ("lcmap", 51)}
    assert all(j.measurement == config.measurement.mode for j in jobs)
    assert jobs[0].config["world"]["reflections"] is False and jobs[0].config["filter"]["multipath"] == "none"
    assert config.world.reflections is True  # the overrides change the jobs' copy only
    effective = effective_config(config, jobs[0])
    assert effective.world.reflections is False and effective.filter.multipath == "none"
    assert len({episode_key(j) for j in jobs}) == len(jobs)


def test_no_trajectories_records_nothing():
    grid = StudyGrid(("helix",), ("lcmap",), ("cv",), episodes=2, first_seed=0, measurement="geometric")
    jobs = build_jobs(grid, EnvConfig())
    assert not any(j.record for j in jobs)
    assert {j.measurement for j in jobs} == {"geometric"} and {j.filter_model for j in jobs} == {None}


def test_the_log_reads_back_what_was_appended_and_skips_a_torn_line(tmp_path):
    config = to_dict(EnvConfig())
    log = EpisodeLog(tmp_path / "episodes.jsonl", config)
    assert log.read() == {}  # no log yet
    log.start()
    keys = [("helix", "lcmap", "cv", "signal", seed, None) for seed in (1, 2)]
    with log.appending() as append:
        for key in keys:
            append(key, {"seed": key[4]})
    assert log.read() == {key: {"seed": key[4]} for key in keys}
    text = log.path.read_text()
    log.path.write_text(text[: len(text) - 10])  # killed while writing the second episode
    assert log.read() == {keys[0]: {"seed": 1}}
    log.path.write_bytes(bytes(range(128, 256)))
    with pytest.raises(LogMismatch, match="is not a text log"):
        log.read()


def test_a_resumed_log_keeps_the_rows_appended_after_a_torn_or_unfinished_line(tmp_path):
    """Resuming cuts a torn last line off before appending, and ends a whole last line that lost its newline, so
    that the episode run again and the next ones read back (they were glued onto the fragment and lost)."""
    log = EpisodeLog(tmp_path / "episodes.jsonl", to_dict(EnvConfig()))
    log.start()
    keys = [("helix", "lcmap", "cv", "signal", seed, None) for seed in (1, 2, 3, 4)]
    with log.appending() as append:
        for key in keys[:2]:
            append(key, {"seed": key[4]})
    text = log.path.read_text()
    for cut in (10, 1):  # torn mid-row, then a whole row without its newline
        log.path.write_text(text[: len(text) - cut])
        done = log.open(resume=True)
        assert set(done) == ({keys[0]} if cut == 10 else set(keys[:2]))
        with log.appending() as append:
            for key in keys:
                if key not in done:
                    append(key, {"seed": key[4]})
        assert log.read() == {key: {"seed": key[4]} for key in keys}
        assert log.path.read_text().count("\n") == 5  # the config and four rows, one a line
        log.path.write_text(text)


def test_the_log_refuses_another_config_or_no_header(tmp_path):
    path = tmp_path / "episodes.jsonl"
    EpisodeLog(path, to_dict(EnvConfig())).start()
    other = to_dict(EnvConfig().replace(episode={"duration": 60.0}))
    with pytest.raises(LogMismatch, match=r"another config \(sections \['episode'\] differ\)"):
        EpisodeLog(path, other).read()
    path.write_text(json.dumps({"key": [], "row": {}}) + "\n")
    with pytest.raises(LogMismatch, match="does not start with a config line"):
        EpisodeLog(path, other).read()


def test_a_log_from_before_a_field_was_added_resumes_but_not_one_with_a_field_removed(tmp_path):
    path = tmp_path / "episodes.jsonl"
    old = to_dict(EnvConfig())
    del old["source"]["keep_within"], old["facility"]  # as a log written before these existed holds it
    EpisodeLog(path, old).start()
    with EpisodeLog(path, old).appending() as append:
        append(("helix", "lcmap", "cv", "signal", 1, None), {"seed": 1})
    assert len(EpisodeLog(path, to_dict(EnvConfig())).read()) == 1
    EpisodeLog(path, to_dict(EnvConfig())).start()
    with pytest.raises(LogMismatch, match=r"another config \(sections \['facility', 'source'\] differ\)"):
        EpisodeLog(path, old).read()  # the log has fields this config does not: another config


def test_a_study_that_gained_variants_resumes_but_not_one_whose_variant_changed(tmp_path):
    from aasl_gym.study.paper import make_study, study_header

    path = tmp_path / "episodes.jsonl"
    header = study_header(make_study("facility"), "cv")
    before = header | {"variants": header["variants"][:1]}  # the log of the study's first variant only
    EpisodeLog(path, before).start()
    with EpisodeLog(path, before).appending() as append:
        append(("facility", "lcmap", "cv", "signal", 1, "cv", "loudest pod"), {"seed": 1})
    assert len(EpisodeLog(path, header).read()) == 1
    changed = header | {"variants": [{"facility": {"pairs": "all"}}, *header["variants"][1:]]}
    with pytest.raises(LogMismatch, match=r"sections \['variants'\] differ"):
        EpisodeLog(path, changed).read()


def test_pool_workers_run_their_linear_algebra_on_one_thread(monkeypatch):
    """A pool's workers are its cores: BLAS threads on top would oversubscribe them. Each spawned worker
    sees one thread per library (unless the user set a count), and the parent's environment is left as
    it was."""
    import os

    from aasl_gym.study.runner import THREAD_VARIABLES, Backend, episode_runner

    for name in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("OMP_NUM_THREADS", "3")  # the user's own choice wins
    with episode_runner(Backend("process", workers=2), os.getenv) as run_all:
        seen = list(run_all(list(THREAD_VARIABLES)))
    assert dict(zip(THREAD_VARIABLES, seen)) == {
        "OMP_NUM_THREADS": "3",
        "OPENBLAS_NUM_THREADS": "1",
        "MKL_NUM_THREADS": "1",
    }
    assert "OPENBLAS_NUM_THREADS" not in os.environ and os.environ["OMP_NUM_THREADS"] == "3"
