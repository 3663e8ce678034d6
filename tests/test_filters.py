"""The vectorized UKF against filterpy, against a linear Kalman filter, and the process models."""

import numpy as np
import pytest
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter as FilterpyUKF
from scipy.integrate import quad_vec, solve_ivp
from scipy.stats import multivariate_normal

from aasl_gym import kernels
from aasl_gym.config import FilterConfig
from aasl_gym.filters import (
    MOTION_MODELS,
    UnscentedKalmanFilter,
    merwe_sigma_points,
    predict_together,
    update_together,
)
from aasl_gym.measurement_models import direct_measurement

FIXED = np.array([0.0, 0, -0.96])


def hx_factory(mobile, mobile_velocity):
    def hx(states):
        return direct_measurement(states[..., 0:3], states[..., 3:6], mobile, mobile_velocity, FIXED) + states[..., -2:]

    return hx


@pytest.mark.parametrize("name", ["cv", "ca", "ctrv"])
def test_matches_filterpy_step_for_step(name):
    config = FilterConfig(motion_model=name, acceleration_psd=1e-3, jerk_psd=1e-4, turn_rate_psd=1e-4)
    model = MOTION_MODELS[name](config)
    ours = UnscentedKalmanFilter(model, alpha=0.5, beta=2.0, kappa=0.0)
    points = MerweScaledSigmaPoints(model.dim, alpha=0.5, beta=2.0, kappa=0.0)
    reference = FilterpyUKF(
        dim_x=model.dim, dim_z=2, dt=0.2, fx=lambda x, dt: model.transition(x[None], dt)[0], hx=None, points=points
    )
    rng = np.random.default_rng(1)
    x0 = np.zeros(model.dim)
    x0[:6] = [8.0, -5, -10, 0.3, 0.2, 0]
    if name == "ctrv":
        x0[6] = 0.05
    p0 = np.eye(model.dim) * 0.5
    ours.initialize(x0, p0)
    reference.x, reference.P, reference.Q = x0.copy(), p0.copy(), model.process_noise(0.2)
    R = np.diag([0.05**2, 0.02**2])
    for k in range(100):
        angle = 0.1 * k
        mobile = np.array([10 * np.cos(angle), 10 * np.sin(angle), -7.0])
        mobile_velocity = np.array([-np.sin(angle), np.cos(angle), 0.0])
        z = direct_measurement(
            np.array([8.0 + 0.06 * k, -5 + 0.04 * k, -10]), np.array([0.3, 0.2, 0]), mobile, mobile_velocity, FIXED
        )
        z = z + rng.normal(0, [0.05, 0.02])
        ours.predict(0.2)
        ours.update(z, R, hx_factory(mobile, mobile_velocity))
        reference.predict()
        reference.update(z, R=R, hx=lambda x: hx_factory(mobile, mobile_velocity)(x[None])[0])  # noqa: B023  (called here)
        np.testing.assert_allclose(ours.x, reference.x, rtol=0, atol=1e-8)
        np.testing.assert_allclose(ours.P, reference.P, rtol=0, atol=1e-8)
        assert ours.log_likelihood == pytest.approx(reference.log_likelihood, abs=1e-8)
        assert ours.nis == pytest.approx(reference.y @ np.linalg.solve(reference.S, reference.y), rel=1e-9)


@pytest.mark.parametrize("name", ["cv", "ca", "ctrv"])
def test_a_batch_predicts_each_filter_as_numpy_predicts_it(name):
    """``predict_together`` (compiled sigma points and moments) against the unscented prediction written with NumPy
    (Merwe's points by NumPy's Cholesky, the weighted moments, the model's reflection), filter by filter, to
    rounding: one of four is near the surface bound and rising through it (reflected), and in a second batch
    another's covariance is not positive definite (left out and left as it was, the others predicted all the
    same)."""
    model = MOTION_MODELS[name](FilterConfig(motion_model=name), depth_bounds=(-59.0, -1.0))
    rng = np.random.default_rng(2)
    starts = []
    for i in range(4):
        x = np.r_[5.0, -3.0, -20.0, rng.normal(0, 0.3, model.dim - 3)]
        if i == 1:
            x[2], x[5] = -0.9, 1.5
        root = rng.normal(0, 0.1, (model.dim, model.dim))
        starts.append((x, root @ root.T + 0.01 * np.eye(model.dim)))
    for broken in (False, True):
        batch, alone = [UnscentedKalmanFilter(model) for _ in starts], [UnscentedKalmanFilter(model) for _ in starts]
        for i, (x, covariance) in enumerate(starts):
            for ukf in (batch[i], alone[i]):
                ukf.initialize(x, -covariance if broken and i == 2 else covariance)
        expected = []
        for i, ukf in enumerate(alone):
            try:
                numpy_predict(ukf, 0.2)
            except np.linalg.LinAlgError:
                continue
            expected.append(i)
        assert predict_together(batch, 0.2) == expected == ([0, 1, 3] if broken else [0, 1, 2, 3])
        for i in expected:
            for attribute in ("x", "P", "sigmas_f"):
                got, reference = getattr(batch[i], attribute), getattr(alone[i], attribute)
                np.testing.assert_allclose(got, reference, rtol=1e-12, atol=1e-14, err_msg=attribute)
        if broken:
            assert np.array_equal(batch[2].P, -starts[2][1])
        assert batch[1].x[2] < -1.0 and batch[1].x[5] < 0  # reflected: back below the bound, going down


def test_a_cv_bank_without_bounds_predicts_in_one_call_as_numpy_predicts_it(monkeypatch):
    """The default world's filters (CV, no depth bounds) take the one-call prediction
    (:func:`aasl_gym.kernels.constant_velocity_prediction`): each filter as the NumPy prediction gives it, to
    rounding."""
    model = MOTION_MODELS["cv"](FilterConfig())
    rng = np.random.default_rng(12)
    batch, alone = [UnscentedKalmanFilter(model) for _ in range(3)], [UnscentedKalmanFilter(model) for _ in range(3)]
    for ukf_batch, ukf_alone in zip(batch, alone):
        root = rng.normal(0, 0.1, (model.dim, model.dim))
        x, covariance = rng.normal(0, 5, model.dim), root @ root.T + 0.01 * np.eye(model.dim)
        ukf_batch.initialize(x, covariance)
        ukf_alone.initialize(x, covariance)
        numpy_predict(ukf_alone, 0.2)
    calls = []
    one_call = kernels.constant_velocity_prediction
    monkeypatch.setattr(kernels, "constant_velocity_prediction", lambda *a: calls.append(1) or one_call(*a))
    assert predict_together(batch, 0.2) == [0, 1, 2]
    assert calls  # the one-call route ran
    for ukf_batch, ukf_alone in zip(batch, alone):
        for attribute in ("x", "P", "sigmas_f"):
            got, reference = getattr(ukf_batch, attribute), getattr(ukf_alone, attribute)
            np.testing.assert_allclose(got, reference, rtol=1e-12, atol=1e-14, err_msg=attribute)


def test_a_batch_updates_each_filter_as_its_own_update_does():
    """``update_together`` (one compiled call for the bank) against each filter's own :meth:`update`, to the last bit;
    a filter whose innovation covariance is not positive definite is left out and left as it was."""
    model = MOTION_MODELS["cv"](FilterConfig())
    rng = np.random.default_rng(13)
    mobile, mobile_velocity = np.array([10.0, 3.0, -6.0]), np.array([0.4, -0.8, 0.0])
    hx = hx_factory(mobile, mobile_velocity)
    z = np.array([2.5, 0.1])
    batch, alone, noises = [], [], []
    for i in range(3):
        x = np.r_[rng.normal([5.0, -4.0, -12.0], 2.0), rng.normal(0, 0.3, 3), 0.0, 0.0]
        covariance = np.diag(rng.uniform(0.05, 0.5, model.dim))
        pair = [UnscentedKalmanFilter(model) for _ in range(2)]
        for ukf in pair:
            ukf.initialize(x, covariance)
            ukf.predict(0.2)
        batch.append(pair[0])
        alone.append(pair[1])
        noises.append(np.diag([-1e6, 0.0]) if i == 1 else np.diag([0.05**2, 0.02**2]))  # i = 1: S not positive
    values = np.stack([hx(ukf.sigmas_f) for ukf in batch])
    x_before = batch[1].x.copy()
    assert update_together(batch, values, z, np.stack(noises)) == [0, 2]
    for i in (0, 2):
        alone[i].update(z, noises[i], hx)
        for attribute in ("x", "P", "nis", "y", "S", "log_likelihood"):
            np.testing.assert_array_equal(getattr(batch[i], attribute), getattr(alone[i], attribute), err_msg=attribute)
    with pytest.raises(np.linalg.LinAlgError):
        alone[1].update(z, noises[1], hx)
    np.testing.assert_array_equal(batch[1].x, x_before)


def numpy_predict(ukf: UnscentedKalmanFilter, dt: float) -> None:
    """The unscented prediction in NumPy, as the filter ran it before its sums were compiled (session 32)."""
    sigmas = merwe_sigma_points(ukf.x, ukf.P, ukf.spread)
    propagated = ukf.model.transition(sigmas, dt)
    mean = ukf.Wm @ propagated
    deviation = propagated - mean
    covariance = (deviation.T * ukf.Wc) @ deviation + ukf.model.process_noise(dt)
    ukf.x, ukf.P = ukf.model.reflect(mean, covariance)
    ukf.sigmas_f = merwe_sigma_points(ukf.x, ukf.P, ukf.spread)


def test_equals_linear_kalman_filter_on_a_linear_model():
    """With a linear measurement the unscented transform is exact: the UKF is the Kalman filter."""
    model = MOTION_MODELS["cv"](FilterConfig(acceleration_psd=1e-2))
    ukf = UnscentedKalmanFilter(model, alpha=0.7, beta=2.0, kappa=0.0)
    H = np.zeros((2, 8))
    H[0, 0], H[0, 6], H[1, 4], H[1, 7] = 1.0, 1.0, 1.0, 1.0
    x, P = np.arange(8.0), np.eye(8) * 2.0
    ukf.initialize(x, P)
    F = np.eye(8)
    F[0:3, 3:6] = 0.2 * np.eye(3)
    Q, R = model.process_noise(0.2), np.diag([0.3, 0.1])
    rng = np.random.default_rng(0)
    for _ in range(30):
        z = rng.normal(size=2)
        ukf.predict(0.2)
        ukf.update(z, R, lambda s: s @ H.T)
        x, P = F @ x, F @ P @ F.T + Q
        S = H @ P @ H.T + R
        assert ukf.log_likelihood == pytest.approx(multivariate_normal.logpdf(z, H @ x, S), abs=1e-9)
        K = P @ H.T @ np.linalg.inv(S)
        x, P = x + K @ (z - H @ x), P - K @ S @ K.T
        np.testing.assert_allclose(ukf.x, x, atol=1e-9)
        np.testing.assert_allclose(ukf.P, P, atol=1e-9)


@pytest.mark.parametrize("name,order", [("cv", 2), ("ca", 3)])
def test_process_noise_is_the_integral_of_white_noise(name, order):
    """Q = int_0^T F(s) G q G^T F(s)^T ds for a white (order)-th derivative, per axis."""
    psd = 0.7
    model = MOTION_MODELS[name](FilterConfig(acceleration_psd=psd, jerk_psd=psd))
    dt = 0.37

    def integrand(s):
        phi = np.array([[1, s, s**2 / 2], [0, 1, s], [0, 0, 1]])[:order, :order]
        g = np.eye(order)[:, -1:]
        return phi @ g @ g.T @ phi.T * psd

    expected, _ = quad_vec(integrand, 0, dt)
    q = model.process_noise(dt)
    axis = [0, 3, 6][:order]
    np.testing.assert_allclose(q[np.ix_(axis, axis)], expected, rtol=1e-10)


def test_coordinated_turn_matches_the_ode():
    model = MOTION_MODELS["ctrv"](FilterConfig())
    x = np.array([1.0, 2, -5, 0.8, -0.4, 0.05, 0.12, 0, 0])
    out = model.transition(x[None], 2.5)[0]

    def rhs(_, y):
        return [y[3], y[4], y[5], -x[6] * y[4], x[6] * y[3], 0.0]

    sol = solve_ivp(rhs, (0, 2.5), x[:6], rtol=1e-11, atol=1e-12)
    np.testing.assert_allclose(out[:6], sol.y[:, -1], atol=1e-8)
    near_zero = x.copy()
    near_zero[6] = 1e-9
    straight = near_zero.copy()
    straight[:3] += 2.5 * near_zero[3:6]
    np.testing.assert_allclose(model.transition(near_zero[None], 2.5)[0][:6], straight[:6], atol=1e-7)


@pytest.mark.parametrize("name", ["cv", "ca", "ctrv"])
def test_a_filter_with_depth_bounds_reflects_where_the_world_does(name):
    """A UKF that only predicts, started on a source (tiny covariance) in a slab of water, keeps its
    mean on the world's source stepping with its specular reflections (motion.advance_source, a second
    implementation) through three bounces; the covariance stays symmetric positive definite."""
    from aasl_gym.motion import Box, SourceState, advance_source

    region = Box(np.inf, -12.0, -2.0)
    model = MOTION_MODELS[name](
        FilterConfig(acceleration_psd=0.0, jerk_psd=0.0, turn_rate_psd=0.0), (region.z_min, region.z_max)
    )
    acceleration = np.array([0.0, 0.01, -0.004]) if name == "ca" else np.zeros(3)
    source = SourceState(
        name,
        np.array([3.0, 1.0, -3.013]),
        np.array([0.4, -0.2, 0.35]),
        acceleration,
        0.05 if name == "ctrv" else 0.0,
        10.0,
    )
    extra = {"cv": [], "ca": acceleration, "ctrv": [source.turn_rate]}[name]
    ukf = UnscentedKalmanFilter(model)
    ukf.initialize(np.concatenate([source.position, source.velocity, extra, [0.0, 0.0]]), np.eye(model.dim) * 1e-10)
    for _ in range(400):  # 80 s: three bounces
        source = advance_source(source, 0.2, region)
        ukf.predict(0.2)
        np.testing.assert_allclose(ukf.x[0:6], np.concatenate([source.position, source.velocity]), atol=1e-5)
    assert np.all(np.linalg.eigvalsh(ukf.P) > 0)


def test_folded_window_trajectories_reflect_where_the_world_does():
    """With ``fold_trajectories`` a state's trajectory, run back from the end of a window, is the world's
    source stepping with its reflections over three bounces."""
    from aasl_gym.motion import Box, SourceState, advance_source

    region = Box(np.inf, -12.0, -2.0)
    model = MOTION_MODELS["cv"](FilterConfig(), (region.z_min, region.z_max), fold_trajectories=True)
    source = SourceState("cv", np.array([3.0, 1.0, -3.013]), np.array([0.4, -0.2, 0.35]), np.zeros(3), 0.0, 10.0)
    path = []
    for _ in range(400):
        path.append(np.concatenate([source.position, source.velocity]))
        source = advance_source(source, 0.2, region)
    path = np.array(path)
    end = np.concatenate([path[-1], [0.0, 0.0]])
    back = model.trajectory(end[None], 0.2 * np.arange(-(len(path) - 1), 1))[0]
    np.testing.assert_allclose(back[:, 0:6], path, atol=1e-9)


@pytest.mark.parametrize("name,speed_limit", [("cv", None), ("ca", None), ("ctrv", None), ("ca", 1.0)])
def test_trajectory_jacobian_matches_central_differences_across_folds(name, speed_limit, rng):
    """d[p, v](t_k)/d x of a window's trajectories, the source's own velocity (closed form for the linear
    models, with the fold's sign where a bound mirrored the state; a speed-limited CA's moving with the time
    it reaches the limit) against central differences of the trajectories themselves."""
    model = MOTION_MODELS[name](FilterConfig(), (-12.0, -2.0), fold_trajectories=True, speed_limit=speed_limit)
    states = np.zeros((6, model.dim))
    states[:, 0:3] = rng.uniform([-20, -20, -11.5], [20, 20, -2.5], (6, 3))
    states[:, 3:6] = rng.uniform(-1.0, 1.0, (6, 3))
    states[:, 6 : model.dim - 2] = rng.uniform(-0.05, 0.05, (6, model.dim - 8))
    if name == "ctrv":  # no turn, and turns whose angle crosses the small-angle series' threshold in the window
        states[:3, 6] = 0.0, 1e-7, 1.7e-6
    lags = np.linspace(-60.0, 0.0, 41)
    assert np.any(np.abs(model.trajectory(states, lags)[..., 5] - states[:, None, 5]) > 0)  # some fold
    if speed_limit:  # at the limit before the window, within it, after it; never; faster, passing outside
        states[:5, 3:9] = [
            [1.8, 0, 0.1, 0.01, 0, 0],
            [1.2, 0, 0.1, 0.01, 0, 0],
            [0.6, 0, 0.1, 0.01, 0, 0],
            [0] * 6,
            [1.8, 0, 0.1, 0.001, 0.01, 0],
        ]
        reached = model._limit_lag(states[:5])
        assert reached[0] < -60 < reached[1] < 0 < reached[2] and reached[3] == np.inf and -60 < reached[4] < 0
    step = 1e-6
    columns = []
    for j in range(model.dim - 2):
        shift = np.zeros(model.dim)
        shift[j] = step
        ahead, behind = model.source_trajectory(states + shift, lags), model.source_trajectory(states - shift, lags)
        columns.append((ahead - behind)[..., 0:6] / (2 * step))
    closed_form = model.trajectory_jacobian(states, lags)
    np.testing.assert_allclose(closed_form, np.stack(columns, -1), rtol=1e-4, atol=1e-5)
    # Together, with one run of the free motion for both (what a window fit reads): the same arrays to the last bit;
    # the free motion itself as every sample's own state runs it (a speed-limited CA takes its lag to the limit once).
    expanded = np.broadcast_to(states[:, None, :], (len(states), len(lags), model.dim))
    np.testing.assert_array_equal(model._free_trajectory(states, lags), model._advance(expanded, lags[None, :, None]))
    trajectory, jacobian = model.trajectory_terms(states, lags)
    np.testing.assert_array_equal(trajectory, model.source_trajectory(states, lags))
    np.testing.assert_array_equal(jacobian, closed_form)


@pytest.mark.parametrize("name", ["cv", "ca"])
def test_the_kept_free_motion_matrices_are_the_motion_itself(name):
    """A linear model's free-motion matrix, kept per distinct lags: each column is the motion of a unit state (the
    model's own ``_advance``), a kept matrix is read-only and served again only for the same lags, and the store
    stays bounded while every matrix it serves stays right."""
    from aasl_gym.filters import FREE_MATRICES_KEPT

    model = MOTION_MODELS[name](FilterConfig())
    moving = model.dim - 2
    for count in [*range(1, FREE_MATRICES_KEPT + 10), 5]:
        lags = -0.2 * np.arange(count)[::-1]
        matrix = model.free_motion_matrix(lags)
        units = np.broadcast_to(np.eye(model.dim)[:moving], (count, moving, model.dim))
        np.testing.assert_array_equal(matrix, np.swapaxes(model._advance(units, lags[:, None, None])[..., 0:6], 1, 2))
        assert len(model._free_matrices) <= FREE_MATRICES_KEPT
    assert model.free_motion_matrix(lags) is model.free_motion_matrix(lags.copy())
    assert model.free_motion_matrix(lags + 0.1) is not model.free_motion_matrix(lags)
    with pytest.raises(ValueError):
        model.free_motion_matrix(lags)[0, 0, 0] = 1.0


def test_a_speed_limited_ca_is_continuous_where_its_line_stops_crossing_the_limit():
    """A state faster than the limit whose line of velocities only grazes the limit's ball, turned a little
    either way (crossing it, passing outside): the trajectories of the two stay together - the model holds a
    line that passes outside where it passes closest, where the crossing's two roots meet."""
    model = MOTION_MODELS["ca"](FilterConfig(), speed_limit=1.0)
    speed, lags = 1.6, np.linspace(-60.0, 20.0, 81)
    grazing = np.arccos(np.sqrt(1 - (1.0 / speed) ** 2))  # the angle of a at which the line touches the ball
    states = np.zeros((2, 11))
    states[:, 3:6] = [speed, 0.0, 0.0]
    for state, angle in zip(states, (grazing - 1e-6, grazing + 1e-6)):
        state[6:9] = 0.01 * np.array([-np.cos(angle), np.sin(angle), 0.0])
    trajectories = model.source_trajectory(states, lags)
    assert np.isfinite(model._limit_lag(states)).all()
    np.testing.assert_allclose(trajectories[0, :, 0:6], trajectories[1, :, 0:6], atol=2e-3)


def test_a_speed_limited_ca_moves_as_the_world_source():
    """A CA source the world stops accelerating at its top speed (motion.advance_source, a second
    implementation), bouncing in a slab: a predict-only UKF of the speed-limited model started on it follows
    it through the limit and three bounces, and the window trajectory run back from its end state retraces
    the world's path. The world steps by 10 ms here: it stops at the end of the step in which it passes
    the limit, the model at the instant."""
    from aasl_gym.motion import Box, SourceState, advance_source

    region = Box(np.inf, -12.0, -2.0)
    model = MOTION_MODELS["ca"](
        FilterConfig(jerk_psd=0.0), (region.z_min, region.z_max), fold_trajectories=True, speed_limit=1.2
    )
    source = SourceState(
        "ca", np.array([3.0, 1.0, -3.013]), np.array([0.6, -0.2, 0.25]), np.array([0.012, 0.006, 0.0]), 0.0, 1.2
    )
    ukf = UnscentedKalmanFilter(model)
    ukf.initialize(np.concatenate([source.position, source.velocity, source.acceleration, [0, 0]]), np.eye(11) * 1e-12)
    path = [np.concatenate([source.position, source.velocity])]
    for _ in range(600):
        for _ in range(20):
            source = advance_source(source, 0.01, region)
        ukf.predict(0.2)
        path.append(np.concatenate([source.position, source.velocity]))
        np.testing.assert_allclose(ukf.x[0:3], source.position, atol=3e-3)
        np.testing.assert_allclose(model.velocity(ukf.x), source.velocity, atol=1e-4)
    path = np.array(path)
    assert np.all(source.acceleration == 0) and np.isclose(np.linalg.norm(source.velocity), 1.2)  # it reached the limit
    assert np.count_nonzero(np.diff(np.sign(path[:, 5]))) >= 3  # and bounced off the bounds three times
    back = model.source_trajectory(ukf.x[None], 0.2 * np.arange(-(len(path) - 1), 1))[0]
    np.testing.assert_allclose(back[:, 0:3], path[:, 0:3], atol=3e-3)
    np.testing.assert_allclose(back[:, 3:6], path[:, 3:6], atol=1e-4)


def test_a_stacked_update_conditioned_on_the_first_pair_is_the_joint_kalman_update():
    """Linear measurements of three pairs whose errors are correlated (a shared term and a common
    navigation error): the UKF's update with pair 0, then :meth:`update_stacked` with the rest conditioned
    on pair 0 (:func:`~aasl_gym.extra_pairs.conditioned_on_first`), equals the linear Kalman filter's one
    update with all six rows and their joint covariance (the UKF is exact for linear h)."""
    from aasl_gym.extra_pairs import conditioned_on_first, joint_noise

    model = MOTION_MODELS["cv"](FilterConfig(motion_model="cv"))
    rng = np.random.default_rng(4)
    H = rng.normal(size=(6, model.dim))
    noises = [np.diag(rng.uniform(0.5, 2.0, 2)) for _ in range(3)]
    shared, receiver = np.diag([0.3, 0.2]), rng.normal(size=(6, 6))
    N = joint_noise(noises, shared, receiver, (0.4, 0.1))
    x0, p0 = rng.normal(size=model.dim), np.diag(rng.uniform(0.5, 2.0, model.dim))
    z = rng.normal(size=6)
    gain = p0 @ H.T @ np.linalg.inv(H @ p0 @ H.T + N)
    x_joint, p_joint = x0 + gain @ (z - H @ x0), p0 - gain @ H @ p0

    ukf = UnscentedKalmanFilter(model)
    ukf.initialize(x0, p0)
    ukf.sigmas_f = merwe_sigma_points(x0, p0, ukf.spread)
    ukf.update(z[:2], N[:2, :2], lambda sigmas: sigmas @ H[:2].T)
    ukf.sigmas_f = merwe_sigma_points(ukf.x, ukf.P, ukf.spread)
    values = ukf.sigmas_f @ H.T
    mean = ukf.Wm @ values
    innovation, deviations, noise = conditioned_on_first(z - mean, values - mean, N)
    ukf.update_stacked(innovation, deviations, noise)
    np.testing.assert_allclose(ukf.x, x_joint, atol=1e-10)
    np.testing.assert_allclose(ukf.P, p_joint, atol=1e-10)


def test_the_compiled_sigma_points_are_merwes_and_flag_a_broken_covariance():
    """:func:`aasl_gym.kernels.sigma_points` against NumPy's Cholesky (``merwe_sigma_points``), to rounding, for a
    batch whose second covariance is not positive definite: flagged, the others' points unchanged by it."""
    from aasl_gym import kernels

    rng = np.random.default_rng(6)
    roots = rng.normal(0, 0.3, (3, 8, 8))
    covariances = roots @ np.swapaxes(roots, 1, 2) + 0.01 * np.eye(8)
    covariances[1, 4, 4] = -1.0
    means = rng.normal(0, 5, (3, 8))
    points, valid = kernels.sigma_points(means, covariances, 2.0)
    assert valid.tolist() == [True, False, True]
    for i in (0, 2):
        np.testing.assert_allclose(points[i], merwe_sigma_points(means[i], covariances[i], 2.0), rtol=0, atol=1e-12)


def test_an_update_takes_the_rd_innovation_modulo_its_period():
    """With a period the RD innovation is wrapped into [-period/2, period/2): a measurement whole periods away updates
    the filter as the one within half a period does, and the NIS is the wrapped innovation's."""
    model = MOTION_MODELS["cv"](FilterConfig())
    filters = [UnscentedKalmanFilter(model) for _ in range(2)]
    for ukf in filters:
        ukf.initialize(np.r_[8.0, -5, -10, 0.3, 0.2, 0, 0, 0], np.eye(8) * 0.2)
        ukf.predict(0.2)
    mobile, mobile_velocity = np.array([10.0, 0, -7]), np.array([0.0, 1, 0])

    def hx(sigmas):
        return direct_measurement(sigmas[:, :3], sigmas[:, 3:6], mobile, mobile_velocity, FIXED) + sigmas[:, -2:]

    z = hx(filters[0].sigmas_f[:1])[0] + np.array([0.2, 0.01])
    filters[0].update(z, np.diag([0.05**2, 0.02**2]), hx, period=1.5)
    filters[1].update(z + np.array([3 * 1.5, 0.0]), np.diag([0.05**2, 0.02**2]), hx, period=1.5)
    np.testing.assert_allclose(filters[1].x, filters[0].x, rtol=0, atol=1e-12)
    assert filters[1].nis == pytest.approx(filters[0].nis, rel=1e-9)
    assert abs(filters[1].y[0]) < 0.75
