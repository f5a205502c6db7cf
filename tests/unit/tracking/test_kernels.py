"""The compiled kernels against their numpy references (:mod:`agent.tracking.filters`,
:mod:`agent.tracking.geometry`) on random inputs."""

from __future__ import annotations

import numpy as np

from agent.tracking import filters as kf, tracker_kernels as tk
from agent.tracking.geometry import line_drift_noise, point_drift_noise, pose_noise_increment


def _spd(rng: np.random.Generator, k: int, n: int, scale: float = 1e-2) -> np.ndarray:
    A = rng.normal(size=(k, n, n)) * scale
    return np.asarray(A @ A.transpose(0, 2, 1) + np.eye(n) * scale**2)


def test_pose_noise_increment(rng: np.random.Generator) -> None:
    for _ in range(20):
        a, b = _spd(rng, 2, 3)
        dx, dy = rng.normal(size=2)
        assert np.allclose(tk.pose_noise_increment(a, b, dx, dy),
                           pose_noise_increment(a, b, dx, dy), atol=1e-14)  # fmt: skip


def test_drift_increment_is_the_positive_part_of_the_target_less_the_drift(
    rng: np.random.Generator,
) -> None:
    k, epochs = 40, 5
    points = rng.normal(size=(k, 2)) * 2.0
    vxy = rng.normal(size=2)
    cov = _spd(rng, epochs, 3)
    epoch = rng.integers(0, epochs, k)
    # Drifts held already: some below the target, some above it, some across (an
    # increment with one negative eigenvalue), and zero.
    drift = np.zeros((k, 3, 3))
    drift[:, :2, :2] = _spd(rng, k, 2, scale=0.05) * rng.choice([0.0, 0.3, 3.0], (k, 1, 1))
    target = point_drift_noise(points, vxy, cov[epoch])
    inc = target - drift[:, :2, :2]
    w, v = np.linalg.eigh(0.5 * (inc + inc.transpose(0, 2, 1)))
    ref = (v * np.clip(w, 0.0, None)[:, None, :]) @ v.transpose(0, 2, 1)
    assert ((w[:, 0] < 0) & (w[:, 1] > 0)).any() and (w[:, 1] <= 0).any() and (w[:, 0] >= 0).any()
    held = drift.copy()
    out = tk.drift_increment(points, vxy, cov, epoch, drift)
    np.testing.assert_allclose(out[:, :2, :2], ref, rtol=0, atol=1e-12)
    assert not out[:, 2].any() and not out[:, :, 2].any()
    np.testing.assert_allclose(drift, held + out, rtol=0, atol=1e-15)


def test_imm_predict_and_combine(rng: np.random.Generator) -> None:
    k, dt, q, sv2 = 6, 0.1, 2.0, 1e-4
    xm = rng.normal(size=(k, 2, 4))
    Pm = _spd(rng, 2 * k, 4).reshape(k, 2, 4, 4)
    mu = rng.dirichlet([1.0, 1.0], size=k)
    Pi = np.array([[0.99, 0.01], [0.05, 0.95]])
    v = rng.normal(size=2)
    delta = _spd(rng, 1, 3)[0]
    held = np.zeros(k, dtype=bool)
    deltas = np.tile(delta, (k, 1, 1))  # one per track (the same here)
    x, P, c = tk.imm_predict(xm, Pm, mu, Pi, dt, q, sv2, v, deltas, held, np.array([0.9, 0.1]),
                             0.25)  # fmt: skip
    x0, P0, c_ref = kf.imm_mix(xm, Pm, mu, Pi)
    Fs, Fc = kf.static_transition(), kf.cv_transition(dt)
    x_ref = np.stack([x0[:, 0] @ Fs.T, x0[:, 1] @ Fc.T], axis=1)
    P_ref = np.stack([Fs @ P0[:, 0] @ Fs.T + np.diag([0, 0, sv2, sv2]),
                      Fc @ P0[:, 1] @ Fc.T + kf.cv_process_noise(dt, q)], axis=1)  # fmt: skip
    Qd = point_drift_noise((c_ref[:, :, None] * x_ref[:, :, :2]).sum(axis=1), v, delta)
    P_ref[:, :, :2, :2] += Qd[:, None]
    assert np.allclose(x, x_ref) and np.allclose(P, P_ref) and np.allclose(c, c_ref)
    xc, Pc = tk.imm_combine(xm, Pm, mu)
    xr, Pr = kf.imm_combine(xm, Pm, mu)
    assert np.allclose(xc, xr) and np.allclose(Pc, Pr)


def test_updates(rng: np.random.Generator) -> None:
    k = 5
    x = rng.normal(size=(k, 4))
    P = _spd(rng, k, 4)
    R = _spd(rng, k, 2)
    nu = rng.normal(size=(k, 2)) * 0.01
    rows = np.arange(k, dtype=np.int64)
    xr, Pr, S_inv, det = kf.update_first_two(x, P, nu, R)
    x2, P2 = x.copy(), P.copy()
    tk.kf_update(x2, P2, rows, nu, R, False)
    assert np.allclose(x2, xr) and np.allclose(P2, Pr)
    # The IMM update: each model updated, probabilities ∝ μ·likelihood.
    xm = rng.normal(size=(k, 2, 4))
    Pm = _spd(rng, 2 * k, 4).reshape(k, 2, 4, 4)
    mu = rng.dirichlet([1.0, 1.0], size=k)
    z = xm[:, 0, :2] + rng.normal(size=(k, 2)) * 0.01
    x_ref, P_ref, S_inv, det = kf.update_first_two(xm, Pm, z[:, None] - xm[:, :, :2], R[:, None])
    ll = kf.log_likelihood_2(z[:, None] - xm[:, :, :2], S_inv, det)
    w = mu * np.exp(ll - ll.max(axis=1, keepdims=True))
    mu_ref = np.clip(w / w.sum(axis=1, keepdims=True), 1e-6, 1.0)
    mu_ref /= mu_ref.sum(axis=1, keepdims=True)
    xm2, Pm2, mu2 = xm.copy(), Pm.copy(), mu.copy()
    tk.imm_update(xm2, Pm2, mu2, rows, z, R, 1e-6)
    assert np.allclose(xm2, x_ref) and np.allclose(Pm2, P_ref) and np.allclose(mu2, mu_ref)


def test_point_costs(rng: np.random.Generator) -> None:
    z = rng.normal(size=(4, 2))
    R = _spd(rng, 4, 2)
    x = rng.normal(size=(3, 2))
    P = _spd(rng, 3, 2)
    d2, cost = tk.point_costs(z, R, x, P)
    S = P[:, None] + R[None]
    nu = z[None] - x[:, None]
    ref = np.einsum("kmi,kmij,kmj->km", nu, np.linalg.inv(S), nu)
    assert np.allclose(d2, ref) and np.allclose(cost, ref + np.log(np.linalg.det(S)))


def test_timed_update_is_an_update_at_the_feature_time(rng: np.random.Generator) -> None:
    # A CV state at t - tau, predicted to t (F, Q(tau)), updated there with a feature taken
    # at t - tau, must equal the update at t - tau predicted to t (exact, so to round-off).
    q, tau = 2.0, 0.07
    F, Q = kf.cv_transition(tau), kf.cv_process_noise(tau, q)
    H = np.hstack([np.eye(2), np.zeros((2, 2))])
    for _ in range(10):
        x_then = rng.normal(size=4)
        P_then = _spd(rng, 1, 4, 0.1)[0]
        z, R = rng.normal(size=2), _spd(rng, 1, 2, 0.05)[0]
        S = H @ P_then @ H.T + R
        K = P_then @ H.T @ np.linalg.inv(S)
        x_ref = F @ (x_then + K @ (z - H @ x_then))
        P_ref = F @ (P_then - K @ S @ K.T) @ F.T + Q
        xm = np.stack([F @ x_then, F @ x_then])[None]
        Pm = np.stack([F @ P_then @ F.T + Q, F @ P_then @ F.T + Q])[None]
        mu = np.array([[0.5, 0.5]])
        tk.imm_update_timed(xm, Pm, mu, np.zeros(1, dtype=np.int64), z[None], R[None],
                            np.array([tau]), np.zeros(1), q, 1e-6)  # fmt: skip
        assert np.allclose(xm[0, 1], x_ref, atol=1e-12)
        assert np.allclose(Pm[0, 1], P_ref, atol=1e-12)
        # Its gating distance is that of the update at the feature's time.
        x_now, P_now = (F @ x_then)[None], (F @ P_then @ F.T + Q)[None]
        d2, _ = tk.point_costs_timed(z[None], R[None], np.array([tau]), np.zeros(1), x_now,
                                     P_now, q)  # fmt: skip
        nu = z - H @ x_then
        assert np.isclose(d2[0, 0], nu @ np.linalg.solve(S, nu), rtol=1e-10)


def test_floor_position_matches_its_reference(rng: np.random.Generator) -> None:
    sigma = 0.003
    # Blocks with both, one and neither eigenvalue below σ², in 2 × 2 and 4 × 4.
    for n in (2, 4):
        P = _spd(rng, 30, n, scale=0.004) * rng.choice([0.05, 0.5, 1.0, 20.0], (30, 1, 1))
        rows = np.flatnonzero(rng.random(30) < 0.7)
        out = P.copy()
        tk.floor_position(out, rows, sigma)
        ref = P.copy()
        ref[rows] = kf.floor_position(P[rows], sigma)
        np.testing.assert_allclose(out, ref, rtol=0, atol=1e-15)
        w = np.linalg.eigvalsh(out[rows][:, :2, :2])
        assert (w >= sigma**2 * (1 - 1e-9)).all()


def test_hit_marks_the_tracks_updated() -> None:
    k = 4
    drift = np.ones((k, 3, 3))
    hits, last, refl_n = np.ones(k, np.int64), np.zeros(k, np.int64), np.zeros(k, np.int64)
    updated, refl_sum = np.zeros(k, bool), np.zeros(k)
    t = np.array([1, 3])
    tk.hit(t, np.array([0.5, np.nan]), 7, drift, hits, updated, last, refl_sum, refl_n)
    assert not drift[t].any() and drift[[0, 2]].all()
    assert hits.tolist() == [1, 2, 1, 2] and updated.tolist() == [False, True, False, True]
    assert last.tolist() == [0, 7, 0, 7]
    assert refl_sum.tolist() == [0.0, 0.5, 0.0, 0.0] and refl_n.tolist() == [0, 1, 0, 0]


def test_feature_times_is_the_mean_and_spread_of_its_samples_ages(
    rng: np.random.Generator,
) -> None:
    pts = rng.uniform(-1.0, 1.0, (300, 2))
    age = rng.uniform(0.0, 0.1, 300)
    centre = rng.uniform(-0.5, 0.5, (6, 2))
    radius = rng.uniform(0.1, 0.4, 6)
    radius[0] = 5.0  # no sample near it
    tau, var = tk.feature_times(centre, radius, pts, age, 0.03)
    d = np.hypot(*(pts[None] - centre[:, None]).transpose(2, 0, 1))
    member = np.abs(d - radius[:, None]) <= 0.03
    assert member[1:].sum(axis=1).min() > 2 and not member[0].any()
    for f in range(1, 6):
        a = age[member[f]]
        assert np.isclose(tau[f], a.mean(), rtol=1e-12) and np.isclose(var[f], a.var(), rtol=1e-9)
    assert tau[0] == 0.0 and var[0] == 0.0


def test_merge_extents_grows_unseen_ends_and_sets_seen_ones() -> None:
    # The line x = 1 (α = 0, ρ = 1): along-line coordinate is y.
    x = np.array([[0.0, 1.0], [0.0, 1.0]])
    ends = np.array([[[1.0, 0.0], [1.0, 1.0]], [[1.0, 0.0], [1.0, 1.0]]])
    seen = np.array([[False, False], [True, True]])
    # Feature ends given high end first: along-line order is restored.
    feat = np.array([[[1.0, 1.5], [1.0, 0.5]], [[1.0, 0.8], [1.0, 0.2]]])
    feat_seen = np.array([[True, False], [False, True]])  # the 1.5 end and the 0.2 end
    tk.merge_extents(x, ends, seen, np.array([0, 1]), feat, feat_seen)
    np.testing.assert_allclose(ends[0, :, 1], [0.0, 1.5], atol=1e-12)
    assert seen[0].tolist() == [False, True]
    # Track 1 saw both ends at 0 and 1; the feature saw an end at 0.2: set there. Its other
    # end (0.8, unseen) lies inside the track's seen end: the track's end stays seen.
    np.testing.assert_allclose(ends[1, :, 1], [0.2, 1.0], atol=1e-12)
    assert seen[1].tolist() == [True, True]
    np.testing.assert_allclose(ends[:, :, 0], 1.0, atol=1e-12)


def test_extents_near_needs_overlap_or_the_gap() -> None:
    x = np.array([[0.0, 1.0]])
    ends = np.array([[[1.0, 0.0], [1.0, 1.0]]])
    feats = np.array(
        [[[1.0, 1.2], [1.0, 2.0]], [[1.0, 1.4], [1.0, 2.0]], [[1.0, -0.5], [1.0, 0.1]]]
    )
    assert tk.extents_near(x, ends, feats, 0.3).tolist() == [[True, False, True]]


def test_add_line_drift_matches_line_drift_noise(rng: np.random.Generator) -> None:
    x = np.stack([rng.uniform(-np.pi, np.pi, 12), rng.uniform(-2, 2, 12)], axis=1)
    P = _spd(rng, 12, 2)
    delta = _spd(rng, 1, 3)[0]
    vxy = rng.normal(size=2)
    out = P.copy()
    tk.add_line_drift(out, x, vxy, delta)
    np.testing.assert_allclose(out, P + line_drift_noise(x[:, 0], vxy, delta), atol=1e-15)


def test_bound_speeds_brings_fast_models_back_along_their_motion() -> None:
    xm = np.zeros((3, 2, 4))
    xm[:, 1, 2:] = [[0.3, 0.4], [1.2, 1.6], [0.0, -3.0]]  # 0.5, 2.0 and 3.0 m/s
    xm[:, 0, 2:] = 5.0  # the static model is left alone
    Pm = np.tile(np.eye(4) * 1e-2, (3, 2, 1, 1))
    assert tk.bound_speeds(xm, Pm, 1.0) == 2
    np.testing.assert_allclose(xm[:, 1, 2:], [[0.3, 0.4], [0.6, 0.8], [0.0, -1.0]])
    np.testing.assert_allclose(
        Pm[1, 1, 2:, 2:], np.eye(2) * 1e-2 + np.outer([0.6, 0.8], [0.6, 0.8])
    )
    assert (xm[:, 0, 2:] == 5.0).all() and (Pm[0] == np.eye(4) * 1e-2).all()


def test_information_kernels(rng: np.random.Generator) -> None:
    # Log-determinants of the position blocks against numpy's, the mixture's against the
    # moment-matched covariance; the bits are ½·log₂ of the ratio, never negative.
    k = 6
    rows = np.array([0, 2, 5], dtype=np.int64)
    P = _spd(rng, k, 4)
    np.testing.assert_allclose(
        tk.position_log_dets(P, rows), np.log(np.linalg.det(P[rows, :2, :2])), rtol=1e-12
    )
    xm = rng.normal(size=(k, 2, 4))
    Pm = _spd(rng, 2 * k, 4).reshape(k, 2, 4, 4)
    mu = rng.dirichlet([1.0, 1.0], size=k)
    _, Pc = kf.imm_combine(xm, Pm, mu)
    np.testing.assert_allclose(
        tk.position_log_dets(tk.imm_combine(xm[rows], Pm[rows], mu[rows])[1], np.arange(3)),
        np.log(np.linalg.det(Pc[rows, :2, :2])),
        rtol=1e-12,
    )  # fmt: skip
    bits = np.zeros(k)
    before = np.log(np.array([4.0, 1.0, 2.0]))
    after = np.log(np.array([1.0, 2.0, 2.0]))  # narrowed 4×, widened, unchanged
    tk.add_information(bits, rows, before, after)
    np.testing.assert_allclose(bits, [1.0, 0.0, 0.0, 0.0, 0.0, 0.0], atol=1e-15)
    tk.add_information(bits, rows[:1], np.array([-np.inf]), np.array([0.0]))
    assert bits[0] == 1.0
