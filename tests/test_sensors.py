"""The two measurement modes behind the one :class:`~aasl_gym.sensors.Sensor` interface: what each says
about its frame (R, SNR) and how a fault's lost frames leave the others untouched."""

import numpy as np
import pytest

from aasl_gym.config import EnvConfig
from aasl_gym.measurement_models import model_snr, signal_noise_sd
from aasl_gym.sensors import GeometricSensor, Sensor, SignalSensor, make_sensor

FIXED = np.array([0.0, 0.0, -0.96])
SOURCE, SOURCE_VELOCITY = np.array([8.0, -6, -12]), np.array([0.3, 0, 0])
MOBILE, MOBILE_VELOCITY = np.array([14.0, 4, -8]), np.zeros(3)


@pytest.mark.parametrize("mode,kind", [("geometric", GeometricSensor), ("signal", SignalSensor)])
def test_each_mode_has_its_sensor_behind_one_interface(mode, kind):
    sensor = make_sensor(EnvConfig().replace(measurement={"mode": mode}))
    assert isinstance(sensor, kind) and isinstance(sensor, Sensor)
    assert sensor.unwrapper.period == pytest.approx(1.5)
    sweep = EnvConfig().replace(measurement={"mode": mode}, source={"waveform": "sweep"})
    assert make_sensor(sweep).unwrapper.period is None


def test_the_geometric_sensor_reports_its_fixed_noise_and_the_snr_model():
    config = EnvConfig().replace(
        measurement={"mode": "geometric", "range_difference_sd": 0.1}, fault={"kind": "dropped", "start": 0.4}
    )
    sensor, rng = make_sensor(config), np.random.default_rng(3)
    sensor.reset(rng)
    for time in (0.2, 0.4):  # a measured frame, then a dropped one
        sensor.measure(rng, time, SOURCE, SOURCE_VELOCITY, MOBILE, MOBILE_VELOCITY, FIXED)
        expected = np.diag([0.1**2, config.measurement.range_rate_difference_sd**2])
        np.testing.assert_array_equal(sensor.covariance(), expected)
        np.testing.assert_array_equal(sensor.snr(), model_snr(config, SOURCE, np.array([MOBILE, FIXED])))


def test_the_signal_sensor_reports_the_noise_of_its_measured_snrs():
    """R is the Cramer-Rao covariance at the frame's measured SNRs (in free field the model's within 1 dB;
    near the surface its reflection cancels much of the direct path); a dropped frame has no SNR."""
    config = EnvConfig().replace(world={"reflections": False}, fault={"kind": "dropped", "start": 0.4})
    sensor, rng = make_sensor(config), np.random.default_rng(3)
    sensor.reset(rng)
    sensor.measure(rng, 0.2, SOURCE, SOURCE_VELOCITY, MOBILE, MOBILE_VELOCITY, FIXED)
    snr = sensor.snr()
    model = model_snr(config, SOURCE, np.array([MOBILE, FIXED]))
    np.testing.assert_allclose(10 * np.log10(snr), 10 * np.log10(model), atol=1.0)
    np.testing.assert_array_equal(sensor.covariance(), np.diag(signal_noise_sd(config, snr[0], snr[1]) ** 2))
    assert np.isnan(sensor.measure(rng, 0.4, SOURCE, SOURCE_VELOCITY, MOBILE, MOBILE_VELOCITY, FIXED)).all()
    assert np.isnan(sensor.snr()).all()


@pytest.mark.parametrize(
    "mode,kind", [("geometric", "dropped"), ("signal", "dropped"), ("signal", "silent"), ("signal", "clipped")]
)
def test_a_faulty_burst_is_lost_and_later_frames_are_untouched(mode, kind):
    """The fault option: every frame from 1 s for 1 s is lost (NaN: dropped, or rejected by the front
    end's detector), none other is, and the frames after the burst are those of a run without the fault
    to the last bit (the burst draws the same noise)."""
    runs = []
    for fault in ("none", kind):
        config = EnvConfig().replace(measurement={"mode": mode}, fault={"kind": fault, "start": 1.0, "duration": 1.0})
        sensor = make_sensor(config)
        rng = np.random.default_rng(7)
        sensor.reset(rng)
        times = 0.2 * np.arange(1, 16)
        runs.append(
            np.array([sensor.measure(rng, t, SOURCE, SOURCE_VELOCITY, MOBILE, MOBILE_VELOCITY, FIXED) for t in times])
        )
    clean, faulty = runs
    lost = np.isnan(faulty[:, 0])
    np.testing.assert_array_equal(lost, (times >= 1.0 - 1e-9) & (times < 2.0 - 1e-9))
    assert not np.isnan(clean).any()
    np.testing.assert_array_equal(faulty[~lost], clean[~lost])
