"""train.py end to end on a tiny job, and what it writes loads back with its normalization."""

import itertools
import os
import pickle
import re
import tempfile
from pathlib import Path

import numpy as np
import pytest
import yaml

import evaluate
import train
from aasl_gym.config import to_dict
from agents.sb3 import load_model, save_model, statistics_path

TINY_SCHEDULE = {
    "schedule": {
        "timesteps": 256,
        "n_envs": 1,
        "eval_every": 128,
        "eval_episodes": 1,
        "eval_seed": 900000,
        "checkpoint_every": 128,
        "normalize_observation": True,
        "normalize_reward": True,
    },
    "ppo": {"n_steps": 64, "batch_size": 32, "n_epochs": 1, "gamma": 0.99},
}


@pytest.fixture
def tiny(tmp_path):
    config = tmp_path / "env.yaml"
    config.write_text(
        yaml.safe_dump(
            {"episode": {"duration": 10.0}, "world": {"reflections": False}, "filter": {"multipath": "none"}}
        )
    )
    hyper = tmp_path / "training.yaml"
    hyper.write_text(yaml.safe_dump(TINY_SCHEDULE))
    return config, hyper


def test_tiny_ppo_run_writes_a_loadable_model_that_evaluate_runs(tiny, tmp_path, capsys, monkeypatch):
    config, hyper = tiny
    out = tmp_path / "run"
    temporary = tmp_path / "tmp"  # the system's temporary directory, as SB3 finds it
    temporary.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(temporary))
    assert (
        train.main(["--algo", "ppo", "--config", str(config), "--hyperparameters", str(hyper), "--out", str(out)]) == 0
    )
    printed = capsys.readouterr().out
    assert "step 128" in printed and "return" in printed  # the periodic evaluation reported
    for name in ("model.zip", "model.vecnormalize.pkl", "config.yaml", "hyperparameters.yaml", "best/model.zip"):
        assert (out / name).stat().st_size > 0
    assert sorted(p.name for p in (out / "checkpoints").glob("*.zip")) == ["ppo_128.zip", "ppo_256.zip"]
    curve = (out / "evaluations.csv").read_text().splitlines()
    assert curve[0].startswith("timesteps,mean_return") and [line.split(",")[0] for line in curve[1:]] == ["128", "256"]
    assert not list(out.rglob(".*"))  # no temporary files left behind
    progress = (out / "progress.csv").read_text().splitlines()  # SB3's own records, the episodes' metrics among them
    assert len(progress) > 1 and "episode/success_1m" in progress[0].split(",")
    assert not list(temporary.glob("SB3-*"))  # SB3 kept its log in the run's folder, not a temporary one

    policy = load_model(f"ppo:{out / 'model.zip'}")
    assert policy.normalizer is not None and not policy.normalizer.training
    obs = np.zeros(21, dtype=np.float32)
    action, _ = policy.predict(obs)
    assert action.shape == (3,) and np.all(np.abs(action) <= 1)
    # The loaded policy sees what training saw: observations through the saved running statistics.
    direct, _ = policy.model.predict(policy.normalizer.normalize_obs(obs), deterministic=True)
    np.testing.assert_array_equal(action, direct)

    report = tmp_path / "eval"
    assert (
        evaluate.main(
            [
                "--policies",
                "helix",
                f"ppo:{out / 'model.zip'}",
                "--motions",
                "static",
                "--episodes",
                "1",
                "--config",
                str(config),
                "--no-plots",
                "--out",
                str(report),
            ]
        )
        == 0
    )
    assert f"ppo:{out / 'model.zip'}" in (report / "report.md").read_text()


def test_bad_training_input_is_named(tiny, tmp_path, capsys):
    config, _ = tiny
    assert train.main(["--config", str(tmp_path / "missing.yaml"), "--out", str(tmp_path)]) == 2
    assert "--config" in capsys.readouterr().err
    broken = tmp_path / "broken.yaml"
    broken.write_text(yaml.safe_dump({"schedule": {"timesteps": 10}, "ppo": {}}))
    assert train.main(["--config", str(config), "--hyperparameters", str(broken), "--out", str(tmp_path)]) == 2
    assert "schedule needs" in capsys.readouterr().err
    wrong = tmp_path / "wrong.yaml"
    wrong.write_text(yaml.safe_dump({**TINY_SCHEDULE, "ppo": {"n_stepz": 64}}))
    assert train.main(["--config", str(config), "--hyperparameters", str(wrong), "--out", str(tmp_path)]) == 2
    assert "n_stepz" in capsys.readouterr().err
    for values, message in (
        ({"learning_rate": "fast"}, "section 'ppo': PPO refused a value (AssertionError"),  # SB3's own checks
        ({"learning_rate": -1.0}, "section 'ppo': PPO refused a value (ValueError: Invalid learning rate"),  # torch's
        ({"policy_kwargs": {"net_arch": "wide"}}, "section 'ppo' has a value PPO cannot use"),
    ):
        wrong.write_text(yaml.safe_dump({**TINY_SCHEDULE, "ppo": values}))
        assert train.main(["--config", str(config), "--hyperparameters", str(wrong), "--out", str(tmp_path)]) == 2
        assert message in capsys.readouterr().err
    for flags, message in ((["--seed", "-1"], "--seed must be >= 0"), (["--out", str(wrong)], "a file is there")):
        with pytest.raises(SystemExit):
            train.main(flags)
        assert message in capsys.readouterr().err
    with pytest.raises(SystemExit):
        train.main(["--algo", "dqn"])
    assert "dqn" in capsys.readouterr().err


def test_a_facility_trains_on_its_own_env_and_is_evaluated_there(tiny, tmp_path, capsys):
    """A facility trains on AASL-Facility-v0 and its model is evaluated there, beside the facility's own patrol (the
    default policy in a facility); an env or a policy that does not fit the config's pods is refused by name (a
    single-pod id would drop the facility's other pods) before anything is written."""
    import json

    config, hyper = tiny
    short = tmp_path / "facility.yaml"  # over the scenario: the attack within the tiny episode
    short.write_text(yaml.safe_dump({**yaml.safe_load(config.read_text()), "facility": {"onset_range": [1.0, 3.0]}}))
    out = tmp_path / "run"
    flags = ["--config", str(short), "--hyperparameters", str(hyper), "--out", str(out)]
    assert train.main(["--scenario", "facility", *flags]) == 2
    assert "AASL-v0 flies one pod and would ignore this config's facility of 8 pods" in capsys.readouterr().err
    assert train.main(["--env", "AASL-Facility-v0", *flags[2:], "--config", str(config)]) == 2
    assert "--env: AASL-Facility-v0 needs a facility" in capsys.readouterr().err
    assert not out.exists()
    assert train.main(["--env", "AASL-Facility-v0", "--scenario", "facility", *flags]) == 0
    model = f"ppo:{out / 'model.zip'}"
    assert f"evaluate.py --config {out / 'config.yaml'} --policies facility {model}" in capsys.readouterr().out
    assert load_model(model).env_id == "AASL-Facility-v0"

    facility = ["--scenario", "facility", "--config", str(short), "--motions", "cv", "--episodes", "1"]
    assert evaluate.prepare(evaluate.parse_args(facility))[1][0].policy == "facility"
    assert evaluate.main([*facility, "--policies", "helix", "--out", str(tmp_path / "refused")]) == 2
    assert "--policies helix: AASL-v0 flies one pod" in capsys.readouterr().err
    for policy in ("facility", model):  # in the default world
        assert evaluate.main(["--policies", policy, "--out", str(tmp_path / "refused")]) == 2
        assert f"--policies {policy}: AASL-Facility-v0 needs a facility" in capsys.readouterr().err
    assert not (tmp_path / "refused").exists()
    report = tmp_path / "eval"
    assert evaluate.main([*facility, "--policies", "facility", model, "--no-plots", "--out", str(report)]) == 0
    rows = json.loads((report / "results.json").read_text())["episodes"]
    assert sorted(row["policy"] for row in rows) == sorted(["facility", model])
    assert all({"pod", "source_pod", "detection_time"} <= set(row) for row in rows)
    # The report's facility section: one line per policy and motion, the detection counted from the rows.
    section = (report / "report.md").read_text().split("## The facility: detection and hand-over")[1].splitlines()
    lines = {line.split(" | ")[0].lstrip("| "): line for line in section if line.startswith(("| facility", "| ppo:"))}
    assert sorted(lines) == sorted(["facility", model])
    patrol = [row for row in rows if row["policy"] == "facility"]
    heard = sum(row["detection_time"] is not None for row in patrol) / len(patrol)
    assert lines["facility"].split(" | ")[2:4] == [str(len(patrol)), f"{heard:.0%}"]


def test_a_model_takes_only_the_statistics_saved_with_it(tiny, tmp_path):
    """The model records its statistics' digest: a corrupt, another save's or a missing file is named; a model saved
    without statistics removes an earlier save's and ignores one put beside it; one saved before the digest takes
    whatever lies beside it, as it always did."""
    config, hyper = tiny
    out = tmp_path / "run"
    assert (
        train.main(["--algo", "ppo", "--config", str(config), "--hyperparameters", str(hyper), "--out", str(out)]) == 0
    )
    model, statistics = out / "model.zip", statistics_path(out / "model.zip")
    policy = load_model(f"ppo:{model}")
    assert policy.normalizer is not None and policy.model.aasl_statistics is not None
    saved = statistics.read_bytes()
    earlier = statistics_path(out / "checkpoints" / "ppo_128.zip").read_bytes()  # the statistics at step 128
    assert pickle.loads(earlier).obs_rms.count < pickle.loads(saved).obs_rms.count
    for data in (b"not a pickle", earlier):
        statistics.write_bytes(data)
        with pytest.raises(ValueError, match="another save's statistics"):
            load_model(f"ppo:{model}")
    with pytest.raises(ValueError, match="device 'gpu9': not a torch device"):
        load_model(f"ppo:{model}", device="gpu9")  # not the model's fault
    with pytest.raises(TypeError, match="expected a string ALGO:PATH"):
        load_model(None)
    with pytest.raises(ValueError, match=f"was trained with ppo: load it as ppo:{model}"):
        load_model(f"a2c:{model}")  # would load as A2C, which shares PPO's policy class, and run as the wrong thing
    statistics.unlink()
    with pytest.raises(FileNotFoundError, match=r"statistics .* are missing"):
        load_model(f"ppo:{model}")
    statistics.write_bytes(saved)
    bare = policy.model
    bare.get_vec_normalize_env = lambda: None  # a run without normalization, into the same folder
    save_model(bare, model)
    assert not statistics.exists()
    statistics.write_bytes(saved)
    assert load_model(f"ppo:{model}").normalizer is None
    del bare.aasl_statistics  # as a model saved before the digest
    bare.save(model)
    assert load_model(f"ppo:{model}").normalizer is not None


def test_training_episodes_log_their_metrics(tmp_path):
    """The episode-metrics callback averages what the env reports on an episode's last step."""
    from agents.sb3 import make_callbacks

    recorded = {}

    class Recorder:
        def record(self, key, value):
            recorded[key] = value

    metrics = make_callbacks(tmp_path, "ppo", lambda: None, [0], 10, 10, print)[2]
    metrics.model = type("Model", (), {"logger": Recorder()})()  # the callback logs through its model's logger
    ends = [
        {"convergence_time": np.array(30.0), "success": {"1.0": True}, "final_error": np.array(0.4)},
        {"convergence_time": np.array(np.nan), "success": {"1.0": False}, "final_error": np.array(2.0)},
    ]
    metrics.locals = {"infos": [ends[0], {"time": 1.0}]}  # a step where one env ended and one did not
    metrics._on_step()
    metrics.locals = {"infos": [ends[1]]}
    metrics._on_step()
    metrics._on_rollout_end()
    assert recorded == {"episode/success_1m": 0.5, "episode/final_error": 1.2, "episode/convergence_time": 30.0}


def test_a_residual_model_is_evaluated_in_the_env_it_was_trained_on(tiny, tmp_path):
    """A model trained on AASL-Greedy-v0 outputs a residual on the planner's command. With its action
    head zeroed it must fly exactly the greedy policy's episode - which holds only if evaluate.py runs it
    in AASL-Greedy-v0, on the same source (to float32 rounding: the greedy policy reads the estimate
    from the observation)."""
    import json

    import torch

    config, hyper = tiny
    out = tmp_path / "run"
    assert (
        train.main(
            ["--env", "AASL-Greedy-v0", "--config", str(config), "--hyperparameters", str(hyper), "--out", str(out)]
        )
        == 0
    )
    policy = load_model(f"ppo:{out / 'model.zip'}")
    assert policy.env_id == "AASL-Greedy-v0"
    with torch.no_grad():
        policy.model.policy.action_net.weight.zero_()
        policy.model.policy.action_net.bias.zero_()
    save_model(policy.model, out / "zero.zip")  # loaded, without its env: saved without statistics
    assert load_model(f"ppo:{out / 'zero.zip'}").env_id == "AASL-Greedy-v0"
    policy.model.aasl_env_id = "AASL-v9"
    policy.model.save(out / "unknown.zip")
    with pytest.raises(ValueError, match="AASL-v9"):
        load_model(f"ppo:{out / 'unknown.zip'}")

    report = tmp_path / "eval"
    assert (
        evaluate.main(
            [
                "--policies",
                "greedy",
                f"ppo:{out / 'zero.zip'}",
                "--motions",
                "cv",
                "--episodes",
                "1",
                "--seed",
                "3",
                "--config",
                str(config),
                "--no-plots",
                "--out",
                str(report),
            ]
        )
        == 0
    )
    greedy, zero = sorted(
        json.loads((report / "results.json").read_text())["episodes"], key=lambda row: row["policy"] != "greedy"
    )
    assert greedy["policy"] == "greedy" and zero["policy"].endswith("zero.zip")
    for key in ("convergence_time", "rmse", "final_error", "time_to_first_estimate"):
        if greedy[key] is None:  # a convergence time of an episode that never converged
            assert zero[key] is None, key
        else:
            assert zero[key] == pytest.approx(greedy[key], rel=1e-4), key


def test_the_shipped_default_policy_loads_with_its_statistics_and_env():
    """models/ppo_default.zip is what `evaluate.py --policies helix ppo:models/ppo_default.zip` runs."""
    from pathlib import Path

    shipped = Path(__file__).resolve().parents[1] / "models" / "ppo_default.zip"
    policy = load_model(f"ppo:{shipped}")
    assert policy.env_id == "AASL-Greedy-v0"
    assert policy.normalizer is not None and not policy.normalizer.training
    action, _ = policy.predict(np.zeros(21, dtype=np.float32))
    assert action.shape == (3,) and np.all(np.isfinite(action))


def test_a_recurrent_policy_trains_and_is_evaluated_with_its_memory_carried(tiny, tmp_path):
    """recurrent-ppo (sb3-contrib) runs end to end, and an episode hands the LSTM state returned by each
    step's prediction to the next one (reset only at the episode's start)."""
    from aasl_gym.env import AASLEnv
    from aasl_gym.registration import ENV_IDS
    from agents.rollout import play_episode

    config, hyper = tiny
    schedule = {
        **TINY_SCHEDULE,
        "recurrent-ppo": {
            "n_steps": 64,
            "batch_size": 32,
            "n_epochs": 1,
            "gamma": 0.99,
            "policy_kwargs": {"lstm_hidden_size": 16},
        },
    }
    hyper.write_text(yaml.safe_dump(schedule))
    out = tmp_path / "run"
    assert (
        train.main(
            ["--algo", "recurrent-ppo", "--config", str(config), "--hyperparameters", str(hyper), "--out", str(out)]
        )
        == 0
    )
    policy = load_model(f"recurrent-ppo:{out / 'model.zip'}")

    calls = []

    class Recording:
        def predict(self, observation, state=None, episode_start=None, deterministic=True):
            action, new_state = policy.predict(observation, state, episode_start, deterministic)
            calls.append((state, bool(episode_start[0]), new_state))
            return action, new_state

    env = AASLEnv(str(config), patrol=ENV_IDS[policy.env_id])
    play_episode(env, Recording(), seed=0)
    assert calls[0][0] is None and calls[0][1]
    assert all(not start and state is previous for (_, _, previous), (state, start, _) in itertools.pairwise(calls))
    hidden = np.asarray(calls[-1][2][0])
    assert hidden.shape[-1] == 16 and np.any(hidden != 0)  # the memory holds something after an episode


ZOO = Path(__file__).resolve().parent.parent / "configs" / "rl_zoo3"
TRAINING = Path(__file__).resolve().parent.parent / "configs" / "training.yaml"


def test_the_schedule_is_validated_with_the_key_named(tmp_path):
    """configs/training.yaml loads; a bad schedule is refused with the offending key and what is allowed."""
    from aasl_gym.config import ConfigError
    from agents.training import load_training, schedule_from_dict, training_record

    schedule, ppo = load_training(TRAINING, "ppo")
    raw = yaml.safe_load(TRAINING.read_text())
    assert to_dict(schedule) == raw["schedule"] and ppo == raw["ppo"]
    assert schedule.eval_seeds == list(range(900000, 900006))
    tiny = schedule_from_dict(TINY_SCHEDULE["schedule"])
    assert tiny.env == "AASL-v0" and tiny.normalize_observation  # an omitted env keeps the default
    bad = [
        ("timesteps", "many", "schedule.timesteps: must be an integer"),
        ("n_envs", 0, "schedule.n_envs: must be an integer >= 1"),
        ("eval_seed", -1, "schedule.eval_seed: must be an integer >= 0"),
        ("normalize_reward", "yes", "schedule.normalize_reward: must be true or false"),
        ("env", "AASL-v9", "schedule.env: 'AASL-v9' is not one of"),
        ("eval_evry", 10, "schedule.eval_evry: unknown key"),
    ]
    for key, value, message in bad:
        with pytest.raises(ConfigError, match=re.escape(message)):
            schedule_from_dict({**TINY_SCHEDULE["schedule"], key: value})
    with pytest.raises(ConfigError, match=r"schedule needs integer .* \(missing: \['n_envs'"):
        schedule_from_dict({"timesteps": 10})
    with pytest.raises(ConfigError, match=r"schedule\.timesteps"):
        tiny.replace(timesteps=0)
    files = [
        ("ppo: {}", "needs a 'schedule' section"),
        ("schedule: {}\nppo: 3", "ppo: must be a mapping"),
        ("schedule: [", "not valid YAML"),
        ("schedule: {}\nppo: {}\nppo: {gamma: 0.9}", "found key 'ppo' twice"),  # PyYAML would keep the last
    ]
    for text, message in files:
        (tmp_path / "h.yaml").write_text(text)
        with pytest.raises(ConfigError, match=re.escape(message)):
            load_training(tmp_path / "h.yaml", "ppo")
    with pytest.raises(ConfigError, match="no file"):
        load_training(tmp_path / "none.yaml", "ppo")
    # A learning rate written as rl-zoo3's files write it without their !!float tag is a number, not a string.
    schedule_only = yaml.safe_dump({"schedule": TINY_SCHEDULE["schedule"]})
    (tmp_path / "h.yaml").write_text(schedule_only + "ppo: {learning_rate: 3e-4}\n")
    assert load_training(tmp_path / "h.yaml", "ppo")[1] == {"learning_rate": 3e-4}
    # The record keeps the file's schedule and, beside it, what the command line changed.
    run = tiny.replace(timesteps=512, env="AASL-Greedy-v0", n_envs=None)
    assert run.n_envs == tiny.n_envs
    record = training_record("ppo", 3, tiny, run, {"gamma": 0.9})
    assert (record["timesteps"], record["env"], record["schedule"]["timesteps"]) == (512, "AASL-Greedy-v0", 256)
    assert record["schedule"]["env"] == "AASL-v0" and record["n_envs"] == 1
    assert record["ppo"] == {"gamma": 0.9} and record["seed"] == 3


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_rl_zoo3_hyperparameters_are_those_of_training_yaml(algo):
    """The shipped rl-zoo3 files hold configs/training.yaml's values for every id they name (one place to tune)."""
    training = yaml.safe_load(TRAINING.read_text())
    schedule, expected = training["schedule"], dict(training[algo])
    zoo = yaml.safe_load((ZOO / f"{algo}.yml").read_text())
    assert set(zoo) == {"AASL-v0", "AASL-Greedy-v0", "AASL-Facility-v0"}
    for env_id, params in zoo.items():
        params = dict(params)
        assert params.pop("n_timesteps") == schedule["timesteps"] and params.pop("n_envs") == schedule["n_envs"], env_id
        assert params.pop("policy") == "MlpPolicy"
        assert eval(params.pop("normalize")) == {
            "norm_obs": schedule["normalize_observation"],
            "norm_reward": schedule["normalize_reward"],
        }
        if "policy_kwargs" in params:
            params["policy_kwargs"] = eval(params["policy_kwargs"])
        assert params == expected, env_id


@pytest.mark.slow
def test_rl_zoo3_trains_the_env_with_the_shipped_hyperparameters(tmp_path):
    """rl-zoo3's own trainer, unmodified, runs one PPO update on AASL-Greedy-v0 from the shipped file
    (geometric measurements, to keep it short) and saves a model that loads."""
    pytest.importorskip("rl_zoo3")
    import subprocess
    import sys

    from stable_baselines3 import PPO

    command = [
        sys.executable,
        "-m",
        "rl_zoo3.train",
        "--algo",
        "ppo",
        "--env",
        "AASL-Greedy-v0",
        "--gym-packages",
        "aasl_gym",
        "--conf-file",
        str(ZOO / "ppo.yml"),
        "-n",
        "1200",
        "--eval-freq",
        "-1",
        "--seed",
        "0",
        "--log-folder",
        str(tmp_path),
        "--env-kwargs",
        "measurement:'geometric'",
    ]
    logs = {**os.environ, "SB3_LOGDIR": str(tmp_path / "sb3")}  # SB3's own log, else a folder in the system's /tmp
    result = subprocess.run(
        command, capture_output=True, text=True, timeout=600, cwd=Path(__file__).resolve().parent.parent, env=logs
    )
    assert result.returncode == 0, result.stderr[-2000:]
    (model,) = tmp_path.glob("ppo/AASL-Greedy-v0_*/AASL-Greedy-v0.zip")
    assert PPO.load(model).n_envs == 2
