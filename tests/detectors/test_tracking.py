"""detectors.tracking: the Kalman filter against filterpy, association and existence on hand-made sequences
with known answers, the three kin cues, fixed-shape output, bad input."""

import math

import numpy as np
import pytest

from detectors.tracking import (
    TRACK_FEATURES,
    TRACK_FIELDS,
    KinTracker,
    TrackerParams,
    TrackKinModel,
    fit_known_circle,
)
from tests.numerics import assert_same_values, same_values

DT = 0.1
STILL = (0.0, 0.0, 0.0)


def _robot_frame(obs_pose, xy):
    """World points ``xy`` (k, 2) seen from an observer at ``obs_pose`` (x, y, theta)."""
    c, s = math.cos(obs_pose[2]), math.sin(obs_pose[2])
    d = np.asarray(xy, float) - obs_pose[:2]
    return np.c_[c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]]


def test_kalman_matches_filterpy():
    from filterpy.common import Q_discrete_white_noise
    from filterpy.kalman import KalmanFilter

    pr = TrackerParams(meas_sigma_rel=0.0, meas_sigma=0.02, process_accel=0.7, init_speed_sigma=0.3)
    tr = KinTracker(pr)
    rng = np.random.default_rng(0)
    truth = np.array([1.0, 0.5]) + np.arange(30)[:, None] * DT * np.array([0.2, -0.1])
    meas = truth + rng.normal(0, 0.02, truth.shape)
    kf = KalmanFilter(dim_x=4, dim_z=2)
    kf.x = np.array([meas[0, 0], 0.0, meas[0, 1], 0.0])  # filterpy order: x, vx, y, vy
    kf.P = np.diag([0.02**2, 0.3**2, 0.02**2, 0.3**2])
    kf.F = np.array([[1, DT, 0, 0], [0, 1, 0, 0], [0, 0, 1, DT], [0, 0, 0, 1]], float)
    kf.H = np.array([[1, 0, 0, 0], [0, 0, 1, 0]], float)
    kf.R = np.eye(2) * 0.02**2
    kf.Q = Q_discrete_white_noise(dim=2, dt=DT, var=0.7**2, block_size=2)
    tr.update(meas[:1], [0.9], STILL, DT)
    for z in meas[1:]:
        kf.predict()
        kf.update(z)
        tr.update(z[None], [0.9], STILL, DT)
        (t,) = tr.tracks()
        np.testing.assert_allclose([t.x, t.vx, t.y, t.vy], kf.x, atol=1e-9)
        np.testing.assert_allclose(t.covariance[np.ix_([0, 2, 1, 3], [0, 2, 1, 3])], kf.P, atol=1e-12)


def test_static_objects_seen_by_a_moving_observer_keep_their_tracks():
    # the observer drives an arc; two posts stay put in the world; odometry is exact here
    posts = np.array([[1.5, 0.3], [1.0, -0.8]])
    tr, pose = KinTracker(), np.zeros(3)
    v, w = 0.2, 0.3
    for k in range(40):
        delta = STILL if k == 0 else (v * DT, 0.0, w * DT)
        if k:  # drive forward, then turn: the increment in the robot frame at the previous frame
            c, s = math.cos(pose[2]), math.sin(pose[2])
            pose = np.array([pose[0] + c * v * DT, pose[1] + s * v * DT, pose[2] + w * DT])
        tr.update(_robot_frame(pose, posts), [0.6, 0.6], delta, DT)
    tracks = tr.tracks()
    assert [t.id for t in tracks] == [0, 1] and all(t.confirmed for t in tracks)
    # tracks live in the odometry frame, here the world frame (the first frame had no increment)
    np.testing.assert_allclose([[t.x, t.y] for t in tracks], posts, atol=1e-6)
    np.testing.assert_allclose(tr.in_robot_frame(), _robot_frame(pose, posts), atol=1e-6)
    assert not any(t.moved for t in tracks)  # static: no motion cue


def test_crossing_targets_keep_their_identities():
    tr = KinTracker(TrackerParams(score_prior=0.5), kin_model="hand")
    for k in range(40):  # two robots cross at 0.2 m/s, 0.5 m apart at the closest
        a = np.array([-1.0 + 0.2 * k * DT, 0.25]) + [2.0, 0.0]
        b = np.array([1.0 - 0.2 * k * DT, -0.25]) + [2.0, 0.0]
        tr.update(np.array([a, b]), [0.7, 0.7], STILL, DT)
    t0, t1 = tr.tracks()
    assert (t0.id, t1.id) == (0, 1)
    assert t0.vx > 0.15 and t1.vx < -0.15  # each kept its own motion through the crossing
    assert t0.moved and t1.moved
    assert tr.kin_prob().min() > 0.99  # both moved: the motion cue


def test_existence_confirms_and_deletes():
    pr = TrackerParams(birth_existence=0.5, p_detect=0.8, clutter_ratio=0.2)
    tr = KinTracker(pr)
    tr.update([[1.0, 0.0]], [0.5], STILL, DT)
    assert len(tr) == 1 and not tr.tracks()[0].confirmed  # p = birth_existence
    tr.update([[1.0, 0.0]], [0.5], STILL, DT)
    assert tr.tracks()[0].confirmed  # 0.5 / (0.5 + 0.5 * 0.2) = 0.83 >= 0.8
    misses = 0
    while len(tr):
        tr.update(np.zeros((0, 2)), [], STILL, DT)
        misses += 1
    assert 3 <= misses <= 6
    # the default confirms at birth (the candidate's own evidence decides whether it is kin)
    assert KinTracker().params.birth_existence >= KinTracker().params.confirm_existence
    # beyond max_range nothing is expected: no misses, the track survives
    tr = KinTracker(pr)
    tr.update([[pr.max_range + 1, 0.0]] * 1, [0.5], STILL, DT)
    for _ in range(20):
        tr.update(np.zeros((0, 2)), [], STILL, DT)
    assert len(tr) == 1


def test_score_cue_is_bounded():
    pr = TrackerParams(min_score=0.0)
    tr = KinTracker(pr, kin_model="hand")
    for _ in range(200):
        tr.update([[1.0, 0.0], [1.0, 1.0]], [0.99, 0.01], STILL, DT)
    kp = tr.kin_prob()
    lim = 1 / (1 + math.exp(-pr.score_clamp))
    assert kp[0] == pytest.approx(lim) and kp[1] == pytest.approx(1 - lim)


def _outline(kind: str, centre, observer, n_views: int, r=0.035, noise=0.0, seed=0):
    """Points on a circle of radius r or a hexagon of circumradius r, as beams from several views."""
    rng = np.random.default_rng(seed)
    views = []
    for k in range(n_views):
        ang = np.linspace(-1, 1, 5) * 0.03 + math.atan2(centre[1] - observer[1], centre[0] - observer[0])
        ang = ang + k * 0.0025  # the beam pattern slides over the object as the observer turns
        pts = []
        for a in ang:
            d = np.array([math.cos(a), math.sin(a)])
            if kind == "circle":
                oc = observer - centre
                b = oc @ d
                disc = b * b - (oc @ oc - r * r)
                if disc < 0:
                    continue
                t = -b - math.sqrt(disc)
            else:
                t = math.inf
                verts = [
                    centre + r * np.array([math.cos(q), math.sin(q)])
                    for q in np.arange(6) * math.pi / 3 + 0.3
                ]
                for i in range(6):
                    p0, p1 = verts[i], verts[(i + 1) % 6]
                    e = p1 - p0
                    m = np.array([d, -e]).T
                    if abs(np.linalg.det(m)) < 1e-12:
                        continue
                    tt, u = np.linalg.solve(m, p0 - observer)
                    if tt > 0 and 0 <= u <= 1:
                        t = min(t, tt)
                if not math.isfinite(t):
                    continue
            t *= 1 + noise * rng.normal()
            pts.append(observer + t * d)
        views.append(np.array(pts))
    return views


@pytest.mark.parametrize("kind,sign", [("circle", 1), ("hexagon", -1)])
def test_outline_cue_tells_a_housing_from_a_hexagon(kind, sign):
    centre = np.array([0.8, 0.0])
    pr = TrackerParams(shape_clamp=2.0, score_prior=0.5)  # the accumulated-outline cue on (default: off)
    tr = KinTracker(pr, kin_model="hand")
    for pts in _outline(kind, centre, np.zeros(2), 20):
        tr.update([centre], [0.5], STILL, DT, points=[pts], noise=0.0)
    (t,) = tr.tracks()
    assert t.points.shape[0] >= 60
    assert sign * tr._lo_shape[tr._rows(0)[0]] >= pr.shape_clamp  # noise-free: decisive
    assert (tr.kin_prob()[0] - 0.5) * sign > 0.3


def test_outline_cue_is_honest_under_noise():
    centre = np.array([0.8, 0.0])
    tr = KinTracker(TrackerParams(shape_clamp=2.0), kin_model="hand")
    for pts in _outline("hexagon", centre, np.zeros(2), 20, noise=0.02):
        tr.update([centre], [0.5], STILL, DT, points=[pts], noise=0.02)
    assert abs(tr._lo_shape[tr._rows(0)[0]]) < 1.0  # 1.6 cm of noise hides a 2 mm deviation


def test_per_frame_residual_cue_separates_a_circle_from_a_hexagon_over_frames():
    """The per-frame known-radius fit residual (noise-normalised LLR), summed over frames: through 1.6 mm
    of range noise one frame's 5 points do not tell a housing from a 7 cm hexagon (their single-frame cues
    overlap over seeds), 25 frames of sliding beams do (every circle above every hexagon); the circle's
    residuals stay at the noise (chi-square per degree of freedom <= 1)."""
    centre, noise = np.array([0.8, 0.0]), 0.002
    first, final, chi, kp = ({"circle": [], "hexagon": []} for _ in range(4))
    for kind in ("circle", "hexagon"):
        for seed in range(8):
            # Gauss-Newton fits (the default takes the residuals at the candidate's centre, exact here)
            pr = TrackerParams(resid_clamp=50.0, score_prior=0.5, frame_fit_iterations=6,
                               frame_fit_warm_start=0)  # fmt: skip
            tr = KinTracker(pr, kin_model="hand")
            for k, pts in enumerate(_outline(kind, centre, np.zeros(2), 25, noise=noise, seed=seed)):
                tr.update([centre], [0.5], STILL, DT, points=[pts], noise=noise)
                row = tr._rows(0)[0]
                if k == 0:
                    first[kind].append(tr._lo_resid[row])
            final[kind].append(tr._lo_resid[row])
            chi[kind].append(tr._res_chi2[row] / tr._res_dof[row])
            kp[kind].append(tr.kin_prob()[0])
    assert min(first["circle"]) < max(first["hexagon"])  # one frame: ambiguous
    assert min(final["circle"]) > max(final["hexagon"]) and min(final["circle"]) > 2.0  # 25 frames: separated
    assert max(chi["circle"]) <= 1.0 < np.median(chi["hexagon"])
    assert min(kp["circle"]) > max(kp["hexagon"])  # the cue enters the kin probability


def test_parked_track_keeps_its_kin_probability_by_default():
    """A static circle the detector keeps accepting stays kin (a parked kin) while another track moves; the
    static penalty (off by default) is what would turn it into a same-radius cylinder. The hand-tuned
    fusion and the shipped classifier alike (the classifier reads the candidates' points: their beams and
    the per-frame circle fits are among its inputs)."""
    arc = 0.035 * np.c_[np.cos(np.linspace(2.5, 3.8, 5)), np.sin(np.linspace(2.5, 3.8, 5))]
    for model in ("hand", "learned"):
        tr = KinTracker(kin_model=model)
        for k in range(50):
            xy = np.array([[1.0, 0.0], [1.5, -0.5 + 0.02 * k]])
            # the visible arc of a housing centred on the candidate (detectors report the housing's centre:
            # the per-frame residuals are taken there)
            tr.update(xy, [0.97, 0.97], STILL, DT, points=[c + arc for c in xy])
        kp = tr.kin_prob()
        assert kp[0] > 0.5 and kp[1] > 0.5, model
        assert not tr.tracks()[0].moved and tr.tracks()[1].moved
    tr = KinTracker(kin_model="hand")
    for k in range(50):
        tr.update([[1.0, 0.0], [1.5, -0.5 + 0.02 * k]], [0.97, 0.97], STILL, DT)
    kp = tr.kin_prob()
    assert kp[0] > 0.5 and kp[1] > 0.99
    assert not tr.tracks()[0].moved and tr.tracks()[1].moved


def test_fit_known_circle_recovers_the_centre():
    rng = np.random.default_rng(1)
    a = rng.uniform(2.0, 4.0, 30)
    pts = np.c_[0.3 + 0.035 * np.cos(a), -0.2 + 0.035 * np.sin(a)]
    c, e = fit_known_circle(pts, 0.035, centre0=(0.28, -0.21))
    np.testing.assert_allclose(c, [0.3, -0.2], atol=1e-9)
    assert np.abs(e).max() < 1e-9


@pytest.mark.parametrize("n_fits", [1, 15, 16, 17, 70])
@pytest.mark.parametrize("warm", [0, 1])
def test_vectorised_frame_fits_are_bitwise_one_fit_at_a_time(n_fits, warm):
    """The per-frame fits, sixteen to a vector (``_frame_fits_kernel``: lanes grouped by point count, short
    lanes padded with weight-0 points, each lane stopping on its own), give every track the residual sums
    of one ``_fit_known_circle`` at a time (the reference tracker's loop), bit for bit: fits of 1-40
    points (fewer than 3 skipped), housings and hexagons, any noise, tracks and candidates in any order."""
    from detectors.tracking import _frame_fits_kernel
    from tests.detectors.reference_tracking import StagedKinTracker

    rng = np.random.default_rng(10 * n_fits + warm)
    pr = TrackerParams(resid_clamp=2.0, frame_fit_warm_start=warm, frame_fit_iterations=2 if warm else 6)
    ref = StagedKinTracker(pr, n_observers=3)
    ref._grow(2 * n_fits)
    ref.poses = rng.uniform(-1, 1, (3, 3))
    ref._obs[:] = rng.integers(0, 3, ref._obs.shape[0])
    ref._res_chi2[:] = rng.uniform(0, 5, ref._res_chi2.shape[0])
    ref._res_dof[:] = rng.integers(0, 9, ref._res_dof.shape[0])
    ref._lo_resid[:] = rng.uniform(-1, 1, ref._lo_resid.shape[0])
    counts = rng.integers(1, 41, n_fits)
    centres = rng.uniform(-2, 2, (n_fits, 2))
    pts = []
    for c, m in zip(centres, counts, strict=True):
        a = rng.uniform(0, 2 * np.pi) + np.linspace(0, rng.uniform(0.3, 2.5), m)
        rad = 0.035 * (1 + (rng.random() < 0.5) * 0.08 * np.cos(6 * a))  # half of them hexagon-like
        pts.append(c + rad[:, None] * np.c_[np.cos(a), np.sin(a)] + rng.normal(0, 0.002, (m, 2)))
    pts = np.concatenate(pts)
    sig = rng.uniform(0.001, 0.02, pts.shape[0])
    cstart = np.r_[0, np.cumsum(counts)].astype(np.int64)
    ti = rng.permutation(2 * n_fits)[:n_fits].astype(np.int64)  # track rows, any order
    ci = rng.permutation(n_fits).astype(np.int64)  # candidate of each
    z = centres + rng.normal(0, 0.01, centres.shape)
    res = [a.copy() for a in (ref._lo_resid, ref._res_chi2, ref._res_dof)]
    dof0 = ref._res_dof.copy()
    _frame_fits_kernel(ti, ci, pts, sig, cstart, ref._obs, ref.poses, z, pr.r, pr.frame_fit_iterations,
                       bool(warm), pr.shape_delta**2, pr.resid_clamp, *res)  # fmt: skip
    ref._frame_fits(ti, ci, pts, sig, cstart, z)
    for name, got in zip(("_lo_resid", "_res_chi2", "_res_dof"), res, strict=True):
        assert np.array_equal(got, getattr(ref, name)), name
    fitted = ti[counts[ci] >= 3]  # every fit of 3 points or more added its degrees of freedom
    assert np.array_equal(res[2][fitted] - dof0[fitted], counts[ci][counts[ci] >= 3] - 2.0)


@pytest.mark.parametrize("clamp, iterations", [(0.0, 0), (2.0, 0), (0.0, 1), (2.0, 3)])
def test_residuals_at_the_candidate_centre_against_numpy_and_the_fits_path(clamp, iterations):
    """The per-frame residuals from the candidate's centre (``_centre_resid_kernel``, robot frame; the
    default takes no Gauss-Newton step) against the staged Python reference bitwise, without a step against
    numpy on the same points, and against the vectorised fits' path with as many steps from the candidate's
    centre (odometry frame, its own noise arithmetic) to rounding: candidates of 1-12 points (fewer than 3
    skipped), tracks and candidates in any order, per-observer noise."""
    from detectors.tracking import _centre_resid_kernel, _frame_fits_kernel, _points_prep
    from tests.detectors.reference_tracking import StagedKinTracker

    rng = np.random.default_rng(int(clamp) + 3)
    pr = TrackerParams(resid_clamp=clamp, frame_fit_iterations=iterations)
    n, n_obs = 60, 3
    ref = StagedKinTracker(pr, n_observers=n_obs)
    ref._grow(2 * n)
    ref.poses = rng.uniform(-1, 1, (n_obs, 3))
    counts = rng.integers(1, 13, n)
    xy = rng.uniform(-2, 2, (n, 2))  # candidate centres, robot frame
    obs = rng.integers(0, n_obs, n)
    ref._obs[:] = rng.integers(0, n_obs, ref._obs.shape[0])
    pts = np.concatenate([c + (0.035 + rng.normal(0, 0.003, m))[:, None]
                          * np.c_[np.cos(a := rng.uniform(0, 6.3) + np.linspace(0, 1.5, m)), np.sin(a)]
                          for c, m in zip(xy, counts, strict=True)])  # fmt: skip
    cstart = np.r_[0, np.cumsum(counts)].astype(np.int64)
    noise = rng.uniform(0.0, 0.02, n_obs)
    ti = rng.permutation(2 * n)[:n].astype(np.int64)
    ci = rng.permutation(n).astype(np.int64)
    sums = [rng.uniform(-1, 1, 2 * n), rng.uniform(0, 5, 2 * n), rng.integers(0, 9, 2 * n).astype(float)]
    for name, v in zip(("_lo_resid", "_res_chi2", "_res_dof"), sums, strict=True):
        getattr(ref, name)[: 2 * n] = v
    got = [v.copy() for v in sums]
    lo, hi = cstart[:-1].copy(), cstart[1:].copy()
    _centre_resid_kernel(ti, ci, pts, lo, hi, xy, obs, noise, pr.shape_sigma**2, pr.r, pr.shape_delta**2,
                         pr.resid_clamp, *got, iterations)  # fmt: skip
    ref._centre_resid(ti, ci, pts, cstart, xy, obs, noise)
    for name, g in zip(("_lo_resid", "_res_chi2", "_res_dof"), got, strict=True):
        assert np.array_equal(g, getattr(ref, name)[: 2 * n]), name
    # numpy, per candidate
    owner = np.repeat(np.arange(n), counts)
    e = np.hypot(*(pts - xy[owner]).T) - pr.r
    v0 = pr.shape_sigma**2 + (noise[obs[owner]] * np.hypot(*pts.T)) ** 2
    chi = np.bincount(owner, e * e / v0, minlength=n)
    fit = counts[ci] >= 3
    if iterations == 0:  # (with steps: the fits' path below)
        np.testing.assert_allclose(got[1][ti] - sums[1][ti], np.where(fit, chi[ci], 0.0), rtol=1e-12, atol=0)
    else:  # a fit lowers every chi-square (Gauss-Newton from a point near the optimum)
        assert np.all(got[1][ti] - sums[1][ti] <= np.where(fit, chi[ci], 0.0) * (1 + 1e-9))
    np.testing.assert_array_equal(got[2][ti] - sums[2][ti], np.where(fit, counts[ci] - 2.0, 0.0))
    if clamp == 0.0:
        assert np.array_equal(got[0], sums[0])
    # the fits' path with no step from the candidate's centre, in the observers' odometry frames
    poses = ref.poses
    cos, sin = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    odom, sig, _ = _points_prep(pts, owner, obs, noise, cos, sin, poses, pr.shape_sigma**2)
    o = obs
    z = np.c_[cos[o] * xy[:, 0] - sin[o] * xy[:, 1] + poses[o, 0], sin[o] * xy[:, 0] + cos[o] * xy[:, 1]
              + poses[o, 1]]  # fmt: skip
    alt = [v.copy() for v in sums]
    _frame_fits_kernel(ti, ci, odom, sig, cstart, ref._obs, poses, z, pr.r, iterations, True,
                       pr.shape_delta**2, pr.resid_clamp, *alt)  # fmt: skip
    np.testing.assert_allclose(alt[1], got[1], rtol=1e-8)
    np.testing.assert_allclose(alt[0], got[0], rtol=1e-8, atol=1e-12)


def test_fit_from_the_candidate_centre_reaches_scipy_least_squares():
    """Gauss-Newton steps from the candidate's centre (``_centre_resid_kernel`` with ``iterations``) reach
    scipy's least-squares optimum of the weighted residuals: the chi-square after 8 steps is scipy's, and
    one step already takes most of the way from the candidate's centre."""
    from scipy.optimize import least_squares

    from detectors.tracking import _centre_resid_kernel

    rng = np.random.default_rng(4)
    pr = TrackerParams()
    s2, r = pr.shape_sigma**2, pr.r
    for _ in range(20):
        m = int(rng.integers(4, 12))
        c = rng.uniform(0.5, 2.0, 2)
        a = rng.uniform(0, 6.3) + np.linspace(0, 1.2, m)
        pts = c + (r + rng.normal(0, 0.002, m))[:, None] * np.c_[np.cos(a), np.sin(a)]
        noise = np.array([0.005])
        v0 = s2 + noise[0] ** 2 * np.sum(pts * pts, axis=1)
        start = c + rng.normal(0, 0.005, 2)  # the detector's centre, a few mm off
        sol = least_squares(lambda q, p=pts, v=v0: (np.hypot(*(p - q).T) - r) / np.sqrt(v), start, xtol=1e-14,
                            ftol=1e-14, gtol=1e-14)  # fmt: skip
        best = 2 * sol.cost
        chi = {}
        for it in (0, 1, 8):
            out = [np.zeros(1), np.zeros(1), np.zeros(1)]
            one = np.zeros(1, np.int64)
            _centre_resid_kernel(one, one, pts, np.array([0]), np.array([m]), start[None], one, noise, s2, r,
                                 pr.shape_delta**2, 0.0, *out, it)  # fmt: skip
            chi[it] = out[1][0]
        assert chi[8] == pytest.approx(best, rel=1e-6, abs=1e-9)
        assert best - 1e-9 <= chi[1] <= chi[0]


def test_static_circle_rejected_once_others_move():
    pr = TrackerParams(static_penalty=-6.0, score_prior=0.5)  # the static penalty on (default: off)
    tr = KinTracker(pr, kin_model="hand")
    steps = int(pr.static_time / DT) + 5
    for k in range(steps):
        tr.update([[1.0, 0.0], [1.5, -0.5 + 0.02 * k]], [0.8, 0.8], STILL, DT)
    kp = tr.kin_prob()
    assert kp[1] > 0.99  # moved
    assert kp[0] < 0.5  # a circle that stays put while the swarm moves


def test_low_scores_are_dropped():
    tr = KinTracker(TrackerParams(min_score=0.2, keep_points=1))
    arc = 0.035 * np.c_[np.cos(np.linspace(2, 4, 4)), np.sin(np.linspace(2, 4, 4))]
    xy = np.array([[1.0, 0.0], [2.0, 0.0], [3.0, 0.0]])
    for _ in range(3):
        tr.update(xy, [0.1, 0.9, 0.05], STILL, DT, points=[p + arc for p in xy], noise=0.01)
    (t,) = tr.tracks()
    assert t.x == pytest.approx(2.0) and t.points.shape == (12, 2)  # its own points only


def test_birth_floor_starts_no_track_from_a_low_score_candidate_but_updates_one():
    """``birth_min_score``: an unmatched candidate below it starts no track, one at or above it does, and a
    candidate below it still updates the track it is associated with (``min_score`` would drop it)."""
    tr = KinTracker(TrackerParams(birth_min_score=0.5))
    tr.update([[1.0, 0.0], [2.0, 0.0], [3.0, 0.0]], [0.3, 0.5, 0.9], STILL, DT)
    assert sorted(t.x for t in tr.tracks()) == pytest.approx([2.0, 3.0])  # 0.3 < the floor: no track
    tr.update([[1.0, 0.0], [2.02, 0.0], [3.0, 0.0]], [0.3, 0.2, 0.9], STILL, DT)
    (a, b) = sorted(tr.tracks(), key=lambda t: t.x)
    assert a.frames_seen == 2 and 2.0 < a.x < 2.02  # updated by a 0.2 candidate, pulled towards it
    assert b.frames_seen == 2 and b.x == pytest.approx(3.0)
    assert len(tr) == 2  # and the 0.3 candidate at 1 m, unmatched again, started nothing
    gated = KinTracker(TrackerParams(min_score=0.25, birth_min_score=0.5))
    gated.update([[2.0, 0.0]], [0.9], STILL, DT)
    gated.update([[2.02, 0.0]], [0.2], STILL, DT)  # below min_score: dropped, the track misses
    (t,) = gated.tracks()
    assert t.frames_seen == 1 and t.x == pytest.approx(2.0)
    off = KinTracker(TrackerParams(min_score=0.0))  # the default floor 0: any score starts a track, as before
    off.update([[1.0, 0.0], [2.0, 0.0]], [-0.5, 0.0], STILL, DT)
    assert len(off) == 2
    with pytest.raises(ValueError, match="birth_min_score"):
        TrackerParams(birth_min_score=1.0)
    with pytest.raises(ValueError, match="birth_min_score"):
        TrackerParams(birth_min_score=-0.1)


def test_track_arrays_fixed_shape():
    tr = KinTracker()
    for k in range(5):
        out = tr.track_arrays(4)
        assert out["tracks"].shape == (1, 4, len(TRACK_FIELDS)) and out["mask"].shape == (1, 4)
        assert int(out["count"][0]) == min(len(tr), 4) == out["mask"].sum()
        tr.update(np.array([[1.0 + 0.3 * j, 0.2 * j] for j in range(k + 1)]), np.full(k + 1, 0.6), STILL, DT)
    assert tr.track_arrays(4)["mask"].all()


def test_batch_equals_separate_trackers():
    """One tracker over 3 observers gives each observer exactly the tracks of its own tracker."""
    rng = np.random.default_rng(3)
    bank, single = KinTracker(n_observers=3), [KinTracker() for _ in range(3)]
    objs = rng.uniform(-2, 2, (3, 5, 2))
    for _ in range(25):
        obs, xy, sc, pts, own, delta = [], [], [], [], [], rng.normal(0, 0.02, (3, 3))
        for o in range(3):
            keep = rng.random(5) < 0.8
            z = objs[o][keep] + rng.normal(0, 0.005, (keep.sum(), 2))
            s = rng.uniform(0.2, 0.9, keep.sum())
            p = [zz + 0.035 * np.c_[np.cos(np.linspace(2, 4, 4)), np.sin(np.linspace(2, 4, 4))] for zz in z]
            single[o].update(z, s, delta[o], DT, points=p, noise=0.005)
            own += [np.full(4, len(xy) + i) for i in range(len(z))]
            obs += [o] * len(z)
            xy += list(z)
            sc += list(s)
            pts += p
        bank.update_batch(np.array(obs), np.array(xy), np.array(sc), delta, DT,
                          np.concatenate(pts), np.concatenate(own), noise=np.full(3, 0.005))  # fmt: skip
    for o in range(3):
        a, b = bank.tracks(o), single[o].tracks()
        assert len(a) == len(b) > 0
        for ta, tb in zip(a, b, strict=True):
            fa = [ta.x, ta.y, ta.vx, ta.vy, ta.kin_prob, ta.existence]
            np.testing.assert_allclose(fa, [tb.x, tb.y, tb.vx, tb.vy, tb.kin_prob, tb.existence], atol=1e-9)
            assert ta.points.shape == tb.points.shape


def test_bad_input():
    tr = KinTracker()
    with pytest.raises(ValueError, match="odom_delta"):
        tr.update([[1.0, 0.0]], [0.5], (0.0, float("nan"), 0.0), DT)
    with pytest.raises(ValueError, match="dt"):
        tr.update([[1.0, 0.0]], [0.5], STILL, 0.0)
    with pytest.raises(ValueError, match="one length"):
        tr.update([[1.0, 0.0]], [0.5, 0.5], STILL, DT)
    with pytest.raises(ValueError, match="points"):
        tr.update([[1.0, 0.0]], [0.5], STILL, DT, points=[])
    with pytest.raises(ValueError, match="n_observers"):
        KinTracker(n_observers=0)
    with pytest.raises(ValueError, match="obs must be observer indices"):
        KinTracker(n_observers=2).update_batch([2], [[1.0, 0.0]], [0.5], np.zeros((2, 3)), DT)
    with pytest.raises(ValueError, match="p_detect"):
        TrackerParams(p_detect=1.5)
    with pytest.raises(ValueError, match="unknown key"):
        TrackerParams.from_dict({"bogus": 1})


def test_segment_points_match_a_per_segment_loop():
    from detectors.tracking import segment_points

    rng = np.random.default_rng(5)
    ranges = rng.uniform(0.2, 3.0, (3, 360))
    ranges[0, 5] = 0.0
    ranges[1, 359] = np.inf
    ranges[2, 10] = 12.0
    angles = np.deg2rad(-np.arange(360.0))
    rows, first, last = np.array([0, 1, 2, 2]), np.array([3, 355, 8, 100]), np.array([7, 2, 12, 100])
    pts, own = segment_points(ranges, angles, rows, first, last, range_max=12.0)
    for k, (row, a, b) in enumerate(zip(rows, first, last, strict=True)):
        idx = np.arange(a, a + (b - a) % 360 + 1) % 360
        r = ranges[row, idx]
        ok = np.isfinite(r) & (r > 0) & (r < 12.0)
        ref = np.c_[r[ok] * np.cos(angles[idx][ok]), r[ok] * np.sin(angles[idx][ok])]
        np.testing.assert_allclose(pts[own == k], ref)
    assert (own == 0).sum() == 4 and (own == 1).sum() == 7 and (own == 2).sum() == 4  # 0.0, inf, 12 dropped
    r32 = ranges.astype(np.float32)  # float32 scans (the envs'): read as they are, the same as widened first
    p32, o32 = segment_points(r32, angles, rows, first, last, range_max=12.0)
    p64, o64 = segment_points(r32.astype(np.float64), angles, rows, first, last, range_max=12.0)
    assert np.array_equal(p32, p64) and np.array_equal(o32, o64)
    ranges[1, 0] = np.nan  # NaN: no return either
    assert (segment_points(ranges, angles, rows, first, last, range_max=12.0)[1] == 1).sum() == 6
    with pytest.raises(ValueError, match=r"beams in \[0, 360\)"):
        segment_points(ranges, angles, rows, first, last + 360)
    with pytest.raises(ValueError, match="one length"):
        segment_points(ranges, angles, rows[:2], first, last)


def _compare(a: KinTracker, b: KinTracker) -> None:
    for o in range(a.n_observers):
        ta, tb = a.tracks(o), b.tracks(o)
        assert [t.id for t in ta] == [t.id for t in tb]
        for x, y in zip(ta, tb, strict=True):
            fx = [x.x, x.y, x.vx, x.vy, x.existence, x.kin_prob]
            np.testing.assert_allclose(fx, [y.x, y.y, y.vx, y.vy, y.existence, y.kin_prob], atol=1e-9)
            np.testing.assert_allclose(x.covariance, y.covariance, atol=1e-12)
            assert (x.confirmed, x.moved, x.frames_seen) == (y.confirmed, y.moved, y.frames_seen)
            assert x.age == y.age


@pytest.mark.parametrize("birth_floor", [0.0, 0.5])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_compiled_frame_kernels_match_the_numpy_implementation(seed, birth_floor):
    """The compiled predict / gate / assign / update / birth / existence / motion kernels give the same
    tracks as the previous numpy implementation (tests/detectors/reference_tracking.py) on crowded
    sequences: crossing movers, clutter, missed detections, ambiguous gates, 4 observers; with a birth
    floor (``birth_min_score``) about half the unmatched candidates start no track."""
    from tests.detectors.reference_tracking import ReferenceKinTracker

    rng = np.random.default_rng(seed)
    n_obs, n_obj = 4, 12
    pr = TrackerParams(score_per_metre=0.5, score_n0=1.0, score_prior=0.7,  # every term of the score cue
                       birth_min_score=birth_floor)  # fmt: skip
    fast, ref = KinTracker(pr, n_observers=n_obs), ReferenceKinTracker(pr, n_observers=n_obs)
    pos = rng.uniform(-1.5, 1.5, (n_obs, n_obj, 2))
    pos[:, n_obj // 2 :] = pos[:, : n_obj // 2] + rng.normal(0, 0.04, (n_obs, n_obj // 2, 2))  # close pairs
    vel = rng.normal(0, 0.3, (n_obs, n_obj, 2)) * (rng.random((n_obs, n_obj, 1)) < 0.5)
    arc = 0.035 * np.c_[np.cos(np.linspace(2.5, 3.8, 3)), np.sin(np.linspace(2.5, 3.8, 3))]
    for _ in range(40):
        pos += vel * DT
        obs, xy, sc, pts, own = [], [], [], [], []
        for o in range(n_obs):
            keep = rng.random(n_obj) < 0.75
            z = pos[o][keep] + rng.normal(0, 0.01, (keep.sum(), 2))
            z = np.r_[z, rng.uniform(-2, 2, (rng.integers(0, 4), 2))]  # clutter
            for zz in z:
                own.append(np.full(3, len(xy)))
                pts.append(zz + arc + rng.normal(0, 0.002, (3, 2)))
                xy.append(zz)
                obs.append(o)
            sc += list(rng.uniform(0.15, 0.95, z.shape[0]))
        delta = rng.normal(0, 0.01, (n_obs, 3))
        acc = rng.random(len(xy)) < 0.5
        pts_all, own_all = np.concatenate(pts), np.concatenate(own)
        args = (np.array(obs), np.array(xy), np.array(sc), delta, DT, pts_all, own_all, np.full(n_obs, 0.01))
        fast.update_batch(*args, accepted=acc)
        ref.update_batch(*args, accepted=acc)
        _compare(fast, ref)
    assert len(fast) > 20


# -- the track-level kin classifier (TrackKinModel) --------------------------------------------------------


def _rule_model(feature: str, weight: float, bias: float, min_frames: int = 0) -> TrackKinModel:
    """A one-layer model whose logit is ``weight * feature + bias`` (identity standardisation)."""
    F = len(TRACK_FEATURES)
    W = np.zeros((F, 1))
    W[TRACK_FEATURES.index(feature), 0] = weight
    return TrackKinModel(np.zeros(F), np.ones(F), [(W, np.array([bias]))], min_frames=min_frames)


def test_track_features_on_a_hand_made_sequence():
    """The classifier's inputs: score logits averaged / max / last, accept share, hit flags, frames, beams,
    range, motion; a track missed this frame reads hit 0 and its last candidate's values stay."""
    tr = KinTracker(TrackerParams(min_score=0.0))
    arc = 0.035 * np.c_[np.cos(np.linspace(2.5, 3.8, 5)), np.sin(np.linspace(2.5, 3.8, 5))]
    scores = [0.5, 0.8, 0.9]
    for k, s in enumerate(scores):
        xy = np.array([[1.0, 0.0], [2.0, 0.05 * k]])  # the second object moves 0.5 m/s
        tr.update_batch([0, 0], xy, [s, 0.3], np.zeros((1, 3)), DT, np.r_[xy[0] + arc, xy[1] + arc[:3]],
                      np.repeat([0, 1], [5, 3]), accepted=[k > 0, False])  # fmt: skip
    f = tr.track_features()
    X = dict(zip(TRACK_FEATURES, f["features"].T, strict=True))
    lg = np.log(np.array(scores) / (1 - np.array(scores)))
    np.testing.assert_allclose(X["mean_logit"], [lg.mean(), math.log(0.3 / 0.7)])
    np.testing.assert_allclose(X["std_logit"], [lg.std(), 0.0], atol=1e-7)
    np.testing.assert_allclose(X["max_logit"][0], lg.max())
    np.testing.assert_allclose(X["last_logit"][0], lg[-1])
    np.testing.assert_allclose(X["accept_rate"], [2 / 3, 0.0])
    np.testing.assert_allclose(X["hit"], [1, 1])
    np.testing.assert_allclose(X["log_frames"], [math.log(3)] * 2)
    np.testing.assert_allclose(X["log_beams"], np.log1p([5, 3]))
    np.testing.assert_allclose(X["range"], [1.0, math.hypot(2.0, 0.1)])
    assert X["moved"][0] == 0 and X["motion_z"][1] > X["motion_z"][0]
    assert np.isfinite(X["resid_z"]).all() and X["resid_z"][0] < 0  # exact circle points: chi2 below dof
    assert f["id"].tolist() == [0, 1] and f["confirmed"].all()
    tr.update_batch([0], [[1.0, 0.0]], [0.9], np.zeros((1, 3)), DT, accepted=[True])  # the mover is missed
    X = dict(zip(TRACK_FEATURES, tr.track_features()["features"].T, strict=True))
    assert X["hit"].tolist() == [1, 0] and X["hit_logit"][1] == -6 and X["hit_accepted"][1] == 0
    assert X["last_logit"][1] == pytest.approx(math.log(0.3 / 0.7))
    # decisions not given: the accept features read 0.5
    tr = KinTracker()
    tr.update([[1.0, 0.0]], [0.9], STILL, DT)
    X = dict(zip(TRACK_FEATURES, tr.track_features()["features"].T, strict=True))
    assert X["accept_rate"][0] == 0.5 and X["last_accepted"][0] == 0.5


def test_kin_model_decides_and_young_tracks_take_the_detectors_decision():
    """With a model, kin_prob is the model's; tracks seen in fewer than ``min_frames`` frames take the
    detector's own decision of their last frame (accepted and updated: kin)."""
    always = _rule_model("hit", 0.0, 5.0, min_frames=3)  # the model alone would call everything kin
    tr = KinTracker(kin_model=always)
    xy = [[1.0, 0.0], [2.0, 0.0]]
    tr.update_batch([0, 0], xy, [0.9, 0.9], np.zeros((1, 3)), DT, accepted=[True, False])
    assert tr.kin_prob().tolist() == [0.75, 0.25]  # young: the detector's decisions
    for _ in range(2):
        tr.update_batch([0, 0], xy, [0.9, 0.9], np.zeros((1, 3)), DT, accepted=[True, False])
    np.testing.assert_allclose(tr.kin_prob(), 1 / (1 + math.exp(-5.0)))  # 3 frames: the model's
    assert [t.is_kin for t in tr.tracks()] == [True, True]
    # hit_only: a track not updated this frame is not kin (the model answers "in view, this frame")
    m = _rule_model("hit", 0.0, 5.0, min_frames=3)
    m = TrackKinModel(m.mean, m.scale, m.layers, info=m.info, min_frames=3, hit_only=True)
    assert TrackKinModel.from_dict(m.to_dict()).hit_only and m.shifted(0.4).hit_only
    assert not m.with_hit_only(False).hit_only and m.with_min_frames(2).hit_only
    tr = KinTracker(kin_model=m)
    for _ in range(3):
        tr.update_batch([0, 0], xy, [0.9, 0.9], np.zeros((1, 3)), DT, accepted=[True, False])
    tr.update_batch([0], xy[:1], [0.9], np.zeros((1, 3)), DT, accepted=[True])  # the second coasts
    assert tr.kin_prob()[0] > 0.99 and tr.kin_prob()[1] == 0.0
    with pytest.raises(ValueError, match="hit_only"):
        TrackKinModel(m.mean, m.scale, m.layers, hit_only=1)
    # the hand-tuned fusion stays selectable and is what "hand" gives
    hand = KinTracker(kin_model="hand")
    assert hand.kin_model is None


def test_kin_model_fit_is_deterministic_and_learns_a_rule():
    rng = np.random.default_rng(0)
    X = rng.normal(size=(400, len(TRACK_FEATURES)))
    y = X[:, 0] + 0.5 * X[:, 3] > 0
    a = TrackKinModel.fit(X, y, l2=1e-4)
    b = TrackKinModel.fit(X, y, l2=1e-4)
    np.testing.assert_array_equal(a.layers[0][0], b.layers[0][0])
    assert ((a.logit(X) > 0) == y).mean() > 0.97
    m = TrackKinModel.fit(X, y, hidden=(4,), l2=1e-4)
    assert ((m.logit(X) > 0) == y).mean() > 0.97
    s = a.shifted(0.8)  # operating point moved to p >= 0.8
    np.testing.assert_allclose(s.logit(X), a.logit(X) - math.log(4.0))
    with pytest.raises(ValueError, match="one length"):
        TrackKinModel.fit(X, y[:-1])


def test_kin_model_json_round_trip_and_bad_files(tmp_path):
    import json

    m = _rule_model("mean_logit", 1.0, -0.5, min_frames=2)
    path = tmp_path / "m.json"
    path.write_text(json.dumps(m.to_dict()))
    n = TrackKinModel.load(path)
    X = np.random.default_rng(1).normal(size=(5, len(TRACK_FEATURES)))
    np.testing.assert_allclose(n.kin_prob(X), m.kin_prob(X))
    assert KinTracker(kin_model=str(path)).kin_model.min_frames == 2
    bad = m.to_dict() | {"features": ["mean_logit"]}
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    with pytest.raises(ValueError, match=r"bad\.json.*re-fit"):
        TrackKinModel.load(tmp_path / "bad.json")
    (tmp_path / "nan.json").write_text(json.dumps(m.to_dict()).replace("-0.5", "NaN"))
    with pytest.raises(ValueError, match="non-finite"):
        TrackKinModel.load(tmp_path / "nan.json")
    with pytest.raises(ValueError, match="unknown|expected"):
        TrackKinModel.from_dict(m.to_dict() | {"extra": 1})
    with pytest.raises(TypeError, match="kin_model"):
        KinTracker(kin_model=3)
    # a misspelt name is not read as a missing JSON only: the message lists the names
    for typo in ("hnad", tmp_path / "missing.json"):
        names = r"must be 'hand', 'learned', 'geometric', a model JSON path .*no such file"
        with pytest.raises(ValueError, match=names):
            KinTracker(kin_model=typo)
    # the shipped model loads and fits this tracker's features
    assert KinTracker(kin_model="learned").kin_model.info.get("threshold") is not None


# -- the fused frame update ------------------------------------------------------------------------------


def _crowded_frames(seed, n_obs=3, n_frames=25):
    """Random candidates (some below ``min_score``), their 3-point arcs and odometry, per frame."""
    rng = np.random.default_rng(seed)
    pos = rng.uniform(-1.5, 1.5, (n_obs, 8, 2))
    vel = rng.normal(0, 0.3, (n_obs, 8, 2)) * (rng.random((n_obs, 8, 1)) < 0.5)
    arc = 0.035 * np.c_[np.cos(np.linspace(2.5, 3.8, 3)), np.sin(np.linspace(2.5, 3.8, 3))]
    for _ in range(n_frames):
        pos += vel * DT
        keep = rng.random((n_obs, 8)) < 0.8
        obs = np.nonzero(keep)[0]
        xy = pos[keep] + rng.normal(0, 0.01, (keep.sum(), 2))
        sc = rng.uniform(0.0, 0.95, xy.shape[0])  # some below min_score (0.1): dropped with their points
        pts = (xy[:, None, :] + arc + rng.normal(0, 0.002, (xy.shape[0], 3, 2))).reshape(-1, 2)
        yield obs, xy, sc, rng.normal(0, 0.01, (n_obs, 3)), pts, np.repeat(np.arange(xy.shape[0]), 3)


@pytest.mark.parametrize("seed", [0, 1])
def test_fused_update_equals_the_staged_steps_with_dropped_and_unsorted_points(seed):
    """The one-call frame update is bitwise the staged steps it replaced (the reference in
    tests/detectors/reference_tracking.py), also when candidates fall below ``min_score`` (their points
    dropped and the rest renumbered) and when the points come unsorted by candidate; the compiled
    classifier inputs and ``track_arrays`` are bitwise the numpy ones (where numpy's float64 math is
    libm's)."""
    from tests.detectors.reference_tracking import StagedKinTracker

    fused, staged = KinTracker(n_observers=3), StagedKinTracker(n_observers=3)
    for f, (obs, xy, sc, delta, pts, own) in enumerate(_crowded_frames(seed)):
        if f % 2:  # shuffled points: the tracker groups them by candidate itself
            order = np.random.default_rng(f).permutation(own.size)
            pts, own = pts[order], own[order]
        acc = sc > 0.5 if f % 3 else None
        fused.update_batch(obs, xy, sc, delta, DT, pts, own, accepted=acc)
        staged.update_batch(obs, xy, sc, delta, DT, pts, own, accepted=acc)
        for name in KinTracker._FIELDS:
            assert np.array_equal(getattr(fused, name), getattr(staged, name)), name
        assert np.array_equal(fused.poses, staged.poses) and np.array_equal(fused.odometer, staged.odometer)
        # the compiled classifier inputs and padded slots (few slots: the ranking decides) vs numpy's
        rows = np.flatnonzero(fused._alive)
        # (numpy's log against libm's: a few ULP apart on AVX-512 CPUs, tests/numerics.py)
        assert_same_values(fused._features_fast(rows), staged._features(rows), "classifier inputs")
        a, b = fused.track_arrays(3), staged.track_arrays(3)
        assert all(same_values(a[key], b[key]) for key in ("tracks", "mask", "count"))
    assert len(fused) > 5


_LEFT_OUT = ("std_logit", "hit_logit", "motion_z", "speed_z", "resid_z", "log_moved")


@pytest.mark.parametrize("hidden, left_out", [((), ()), ((8,), ()), ((5, 3), ()), ((8,), _LEFT_OUT),
                                              ((4,), _LEFT_OUT[1:4]), ((), _LEFT_OUT[:1])])  # fmt: skip
def test_the_compiled_kin_decision_is_bitwise_the_models(hidden, left_out):
    """track_arrays' kin decision (``KinTracker._decide``: the classifier's inputs and first layer compiled,
    only for the tracks the network decides) gives every track ``TrackKinModel.kin_prob`` of its features
    bit for bit: logistic, one and two tanh layers, young tracks (``min_frames``), ``hit_only`` on and
    off, and models with inputs left out (their first-layer rows 0: not computed by the compiled decision);
    the padded slots carry it."""
    rng = np.random.default_rng(len(hidden) + 3 * len(left_out))
    F = len(TRACK_FEATURES)
    X = rng.normal(0, 1, (200, F))
    y = (X[:, 0] + 0.5 * rng.normal(0, 1, 200) > 0).astype(float)
    base = TrackKinModel.fit(X, y, hidden=hidden, max_iter=30)
    for name in left_out:
        base.layers[0][0][TRACK_FEATURES.index(name)] = 0.0
    base = TrackKinModel(rng.normal(0, 0.5, F), rng.uniform(0.5, 2, F), base.layers)
    frames = list(_crowded_frames(7, n_frames=12))
    seen = set()  # which branches of the decision the tracks took
    for min_frames, hit_only in ((0, False), (3, True), (4, False)):
        model = base.with_min_frames(min_frames).with_hit_only(hit_only)
        tr = KinTracker(n_observers=3, kin_model=model)
        for obs, xy, sc, delta, pts, own in frames:
            tr.update_batch(obs, xy, sc, delta, DT, pts, own, accepted=sc > 0.5)
            rows, kp = tr._decide()
            assert np.array_equal(rows, np.flatnonzero(tr._alive))
            assert np.array_equal(kp, model.kin_prob(tr._features_fast(rows)))
            a = tr.track_arrays(32)
            got = a["tracks"][..., 6][a["mask"]]
            want = np.sort(np.float32(kp))[::-1]  # every track in a slot: the same values
            assert np.array_equal(np.sort(got)[::-1], want)
            young = np.isin(kp, (0.25, 0.75))
            seen |= {"coasting"} if np.any(kp == 0) else set()
            seen |= {"young"} if young.any() else set()
            seen |= {"network"} if np.any(~young & (kp > 0)) else set()
    assert seen == {"coasting", "young", "network"}


def test_packed_state_survives_growth_copies_and_reading_every_other_frame():
    """The per-track scalars live in packed arrays (``_F``, ``_I``, ``_B``) whose rows the old names view:
    after the capacity doubles, after a deepcopy and after a pickle round trip the views are the packed
    rows, and a copy goes on bitwise as the original. Reading ``track_arrays`` every other frame (the kin
    decision computed inside the next update, or lazily) gives what a tracker read every frame gives."""
    import copy
    import pickle

    frames = list(_crowded_frames(11, n_obs=3, n_frames=16))
    every, other = KinTracker(n_observers=3), KinTracker(n_observers=3)
    cap0 = every._alive.shape[0]
    for f, (obs, xy, sc, delta, pts, own) in enumerate(frames[:8]):
        for tr in (every, other):
            tr.update_batch(obs, xy, sc, delta, DT, pts, own, accepted=sc > 0.5)
        a = every.track_arrays(8)
        if f % 2:
            b = other.track_arrays(8)
            assert all(np.array_equal(a[k], b[k]) for k in ("tracks", "mask", "count"))
    assert every._alive.shape[0] > cap0  # grown
    copies = [copy.deepcopy(every), pickle.loads(pickle.dumps(every))]
    for tr in (every, *copies):
        assert np.shares_memory(tr._exist, tr._F) and np.shares_memory(tr._alive, tr._B)
        assert np.shares_memory(tr._seen, tr._I)
    for obs, xy, sc, delta, pts, own in frames[8:]:
        outs = []
        for tr in (every, *copies):
            tr.update_batch(obs, xy, sc, delta, DT, pts, own, accepted=sc > 0.5)
            outs.append(tr.track_arrays(8))
        for tr in copies:
            for name in KinTracker._FIELDS:
                assert np.array_equal(getattr(tr, name), getattr(every, name)), name
        assert all(np.array_equal(o[k], outs[0][k]) for o in outs[1:] for k in ("tracks", "mask", "count"))


@pytest.mark.parametrize("m", [1, 3, 8])
def test_dense_layer_sums_each_output_in_the_inputs_order(m):
    """``_dense_layer`` (a narrow output layer summed across rows, a wide one across units) gives every
    output ``b[j] + h[r, 0] W[0, j] + h[r, 1] W[1, j] + ...`` left to right, as a Python loop: bitwise."""
    from detectors.tracking import _dense_layer

    rng = np.random.default_rng(m)
    h, W, b = rng.normal(0, 1, (37, 8)), rng.normal(0, 1, (8, m)), rng.normal(0, 1, m)
    want = np.empty((37, m))
    for r in range(37):
        for j in range(m):
            acc = float(b[j])
            for i in range(8):
                acc += float(h[r, i]) * float(W[i, j])
            want[r, j] = acc
    assert np.array_equal(_dense_layer(h, W, b), want)


def test_association_of_dense_clusters_is_bitwise_the_previous_kernel():
    """Objects packed within each other's gates (many gated pairs per candidate: the pair buffer grows,
    the Hungarian solves large components) and spread along x and y (the x-sorted search skips most
    tracks): the fused update reproduces the staged one, whose association is the kernel before the
    x-sorted search, bit for bit."""
    from tests.detectors.reference_tracking import StagedKinTracker

    rng = np.random.default_rng(5)
    fused, staged = KinTracker(n_observers=2), StagedKinTracker(n_observers=2)
    centre = np.array([[1.0, 0.5], [-0.5, 2.0], [3.0, -1.0]])
    for _ in range(12):
        obs, xy = [], []
        for o in range(2):
            for c in centre:  # a cluster of 10 within 2 cm, and a few loners along x
                xy += list(c + rng.normal(0, 0.01, (10, 2)))
                obs += [o] * 10
            xy += list(np.c_[rng.uniform(-4, 4, 5), rng.uniform(-0.2, 0.2, 5)])
            obs += [o] * 5
        xy = np.array(xy)
        sc = rng.uniform(0.2, 0.95, xy.shape[0])
        delta = rng.normal(0, 0.005, (2, 3))
        for tr in (fused, staged):
            tr.update_batch(np.array(obs), xy, sc, delta, DT)
        for name in KinTracker._FIELDS:
            assert np.array_equal(getattr(fused, name), getattr(staged, name)), name
    assert len(fused) >= 60


def test_crowded_observers_and_tied_positions_are_bitwise_the_staged_tracker():
    """An observer with more than 64 tracks (the x-sort and the slots' ranking take their insertion-sort
    paths) beside one with fewer (the counted ranks), candidates sharing x coordinates exactly (the x-sort
    is stable) and many tied kin probabilities (the slots break ties by id): every state array and the
    padded slots, few and many, are bitwise the staged tracker's (its association is the kernel before the
    counted x-sort, its slots numpy's lexsort)."""
    from tests.detectors.reference_tracking import StagedKinTracker

    rng = np.random.default_rng(11)
    fused, staged = KinTracker(n_observers=2), StagedKinTracker(n_observers=2)
    grid = np.round(np.linspace(-4.0, 4.0, 45), 3)
    ones = rng.uniform(-3, 3, (20, 2))
    for f in range(10):
        # observer 0: 90 objects on a grid, pairs sharing an x; observer 1: 20
        xy0 = np.c_[np.repeat(grid, 2), np.tile([-1.5, 1.5], 45)] + rng.normal(0, 0.003, (90, 2)) * (f > 0)
        xy0[::2, 0] = xy0[1::2, 0]  # exact ties in x
        xy1 = ones + rng.normal(0, 0.003, (20, 2))
        xy1[::2, 0] = xy1[1::2, 0]
        keep0 = rng.random(90) < 0.85
        xy = np.r_[xy0[keep0], xy1]
        obs = np.r_[np.zeros(keep0.sum(), np.int64), np.ones(20, np.int64)]
        sc = rng.uniform(0.15, 0.95, obs.size)
        delta = np.zeros((2, 3)) if f == 0 else rng.normal(0, 0.003, (2, 3))
        for tr in (fused, staged):
            tr.update_batch(obs, xy, sc, delta, DT, accepted=sc > 0.6)
        for name in KinTracker._FIELDS:
            assert np.array_equal(getattr(fused, name), getattr(staged, name)), name
        for m in (5, 200):
            a, b = fused.track_arrays(m), staged.track_arrays(m)
            assert all(same_values(a[key], b[key]) for key in ("tracks", "mask", "count")), m
    n0 = np.count_nonzero(fused._alive & (fused._obs == 0))
    assert n0 > 64 and np.count_nonzero(fused._alive & (fused._obs == 1)) < 64


def test_points_prep_is_the_numpy_transform():
    """The points' odometry-frame transform, noise and range (one vector pass after a gather) against the
    same arithmetic in numpy, per point with its candidate's observer, bit for bit."""
    from detectors.tracking import _points_prep

    rng = np.random.default_rng(4)
    n_obs, k, n = 5, 40, 300
    obs = rng.integers(0, n_obs, k)
    owner = np.sort(rng.integers(0, k, n))
    pts = rng.normal(0, 2, (n, 2))
    noise, poses = rng.uniform(0, 0.02, n_obs), rng.normal(0, 1, (n_obs, 3))
    cos, sin = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    odom, sig, dist = _points_prep(pts, owner, obs, noise, cos, sin, poses, 0.0005**2)
    o = obs[owner]
    d = np.sqrt(pts[:, 0] * pts[:, 0] + pts[:, 1] * pts[:, 1])
    assert np.array_equal(dist, d)
    assert np.array_equal(sig, np.sqrt(0.0005**2 + (noise[o] * d) ** 2))
    assert np.array_equal(odom[:, 0], cos[o] * pts[:, 0] - sin[o] * pts[:, 1] + poses[o, 0])
    assert np.array_equal(odom[:, 1], sin[o] * pts[:, 0] + cos[o] * pts[:, 1] + poses[o, 1])


def test_points_scan_is_the_sequential_scan():
    """The branch-free points' check (the fused update's) gives the sequential scan's status on sorted,
    unsorted, out-of-range and non-finite inputs (the first bad point deciding), and the same candidate
    point ranges when the points are fine."""
    from detectors.tracking import _points_scan, _points_scan_seq

    rng = np.random.default_rng(3)
    statuses = set()
    for trial in range(400):
        k = int(rng.integers(0, 12))
        n = int(rng.integers(0, 30))
        owner = np.sort(rng.integers(0, max(k, 1), n)) if k else np.zeros(n, np.int64)
        pts = rng.normal(0, 1, (n, 2))
        kind = trial % 5
        if n and kind == 1:  # unsorted
            owner = rng.permutation(owner)
        if n and kind == 2:  # an owner out of range, maybe after a non-finite point
            owner[rng.integers(0, n)] = rng.choice([-1, k])
            if rng.random() < 0.5:
                pts[rng.integers(0, n), rng.integers(0, 2)] = np.nan
        if n and kind == 3:  # non-finite points
            pts[rng.integers(0, n), rng.integers(0, 2)] = rng.choice([np.nan, np.inf, -np.inf])
        a, b = np.full(k + 1, -7, np.int64), np.full(k + 1, -7, np.int64)
        s_fast, s_seq = _points_scan(pts, owner, k, a), _points_scan_seq(pts, owner, k, b)
        assert s_fast == s_seq, (trial, s_fast, s_seq)
        if s_seq == 0:
            assert np.array_equal(a, b)
        statuses.add(int(s_seq))
    assert statuses == {0, 1, 2, 3}


def test_bad_frame_raises_before_any_state_changes():
    frames = list(_crowded_frames(3, n_frames=6))
    tr = KinTracker(n_observers=3)
    for obs, xy, sc, delta, pts, own in frames[:5]:
        tr.update_batch(obs, xy, sc, delta, DT, pts, own)
    before = {name: getattr(tr, name).copy() for name in (*KinTracker._FIELDS, "poses", "odometer")}
    obs, xy, sc, delta, pts, own = frames[5]
    bad_pts, bad_own, bad_delta, bad_xy = pts.copy(), own.copy(), delta.copy(), xy.copy()
    bad_pts[-1, 0] = np.nan
    bad_own[-1] = xy.shape[0]
    bad_delta[1, 2] = np.inf
    bad_xy[0, 1] = np.nan
    cases = [
        ((obs, xy, sc, delta, DT, bad_pts, own), "points must be finite"),
        ((obs, xy, sc, delta, DT, pts, bad_own), "owner must give each"),
        ((obs, xy, sc, bad_delta, DT, pts, own), "odom_delta"),
        ((obs, bad_xy, sc, delta, DT, pts, own), "must be finite and of one length"),
        ((obs + 3, xy, sc, delta, DT, pts, own), r"obs must be observer indices in \[0, 3\)"),
    ]
    for args, match in cases:
        with pytest.raises(ValueError, match=match):
            tr.update_batch(*args)
        with pytest.raises(ValueError, match="noise must be 3"):
            tr.update_batch(obs, xy, sc, delta, DT, pts, own, noise=[0.01, -1.0, 0.01])
        for name, value in before.items():
            assert np.array_equal(getattr(tr, name), value), name
    tr.update_batch(obs, xy, sc, delta, DT, pts, own)  # the good frame still goes through
    assert not np.array_equal(tr.poses, before["poses"])


def test_track_arrays_are_fresh_and_follow_updates_and_the_kin_model():
    """track_arrays evaluates the kin decision once per frame: a second call gives equal, fresh arrays; an
    update, or another kin model, gives what a tracker without the cache gives."""
    frames = list(_crowded_frames(4, n_frames=8))

    def run(n, kin_model="learned"):
        tr = KinTracker(n_observers=3, kin_model=kin_model)
        for obs, xy, sc, delta, pts, own in frames[:n]:
            tr.update_batch(obs, xy, sc, delta, DT, pts, own)
        return tr

    def same(a, b):
        return all(np.array_equal(a[k], b[k]) for k in ("tracks", "mask", "count"))

    tr = run(6)
    a, b = tr.track_arrays(16), tr.track_arrays(16)
    assert same(a, b) and a["tracks"] is not b["tracks"]
    tr.kin_model = None  # the hand-tuned fusion from now on
    assert same(tr.track_arrays(16), run(6, "hand").track_arrays(16))
    assert not same(tr.track_arrays(16), a)
    tr.kin_model = run(1).kin_model
    obs, xy, sc, delta, pts, own = frames[6]
    tr.update_batch(obs, xy, sc, delta, DT, pts, own)
    assert same(tr.track_arrays(16), run(7).track_arrays(16))


def test_adopt_refuses_a_bad_observer_or_tracker():
    tr = KinTracker(n_observers=2)
    with pytest.raises(ValueError, match=r"observer must be in \[0, 2\), got 2"):
        tr.adopt(2, KinTracker())
    with pytest.raises(ValueError, match="observer must be in"):
        tr.adopt(True, KinTracker())
    for other in (KinTracker(n_observers=2), KinTracker(TrackerParams(score_prior=0.5)), "tracker"):
        with pytest.raises(ValueError, match="one-observer KinTracker with the same params"):
            tr.adopt(0, other)
    assert tr.adopt(1, KinTracker()).shape == (0,)  # an empty tracker adopts nothing


def test_compiled_exp_tanh_and_logistic_against_numpy():
    """The classifier's compiled ``exp`` (``_exp_into``), ``tanh`` and logistic (the track classifier and the
    tracker's kin decision share them) against numpy's on a grid over their whole range and random values:
    exp within 2 ulp (relative), tanh and the logistic within 4e-16 (absolute); the clips hold (no inf, no
    NaN) and tanh is odd and saturates to ±1."""
    from detectors.tracking import _exp_into, _sigmoid, _tanh

    rng = np.random.default_rng(3)
    tiny = [0.0, -0.0, 1e-300, -1e-300]
    x = np.concatenate([np.linspace(-700, 700, 100001), rng.normal(0, 4, 50000), tiny])
    e = np.empty_like(x)
    _exp_into(x, e, -700.0, 700.0)
    np.testing.assert_allclose(e, np.exp(x), rtol=2 * np.finfo(float).eps, atol=0)
    _exp_into(np.array([-1e6, 1e6]), e[:2], -700.0, 700.0)  # clipped
    np.testing.assert_allclose(e[:2], np.exp([-700.0, 700.0]), rtol=2 * np.finfo(float).eps)
    for lim in (1.0, 50.0):
        h = x[np.abs(x) < lim]
        t = _tanh(h)
        np.testing.assert_allclose(t, np.tanh(h), rtol=0, atol=4e-16)
        np.testing.assert_allclose(t, -_tanh(-h), rtol=0, atol=4e-16)
    assert _tanh(np.array([25.0, -25.0, 1e9])).tolist() == [1.0, -1.0, 1.0]
    s = _sigmoid(x)
    with np.errstate(over="ignore"):
        want = 1.0 / (1.0 + np.exp(-x))
    np.testing.assert_allclose(s, want, rtol=0, atol=4e-16)
    assert np.all(np.isfinite(s)) and s.min() >= 0 and s.max() <= 1
    # a (2, 3) block through _tanh keeps its shape
    assert _tanh(np.ones((2, 3))).shape == (2, 3)


_FITS_BEHIND = {"frame_fit_iterations": 6, "frame_fit_warm_start": 0}


@pytest.mark.parametrize("over", [{}, {"keep_points": 1}, _FITS_BEHIND, {"shape_clamp": 2.0},
                                  {"birth_min_score": 0.5}, {"frame_residuals": 0},
                                  {**_FITS_BEHIND, "frame_residuals": 0, "keep_points": 1}])  # fmt: skip
def test_dropped_candidates_points_in_place_or_copied_equal_the_staged_steps(over):
    """Candidates below ``min_score`` dropped (most of them, as in the learned feed) while their points stay
    in place (the default: the kept candidates' point ranges read where they are) or are copied in order (the
    fits from behind the points and the outline ring, which read each point's owner), with candidates of 0
    to 6 points (empty ones first, last and in between) and unsorted points on some frames: every state array
    bitwise the staged steps' (tests/detectors/reference_tracking.py), frame after frame."""
    from tests.detectors.reference_tracking import StagedKinTracker

    rng = np.random.default_rng(len(over) + 5)
    pr = TrackerParams(**over)
    fused, staged = KinTracker(pr, n_observers=2), StagedKinTracker(pr, n_observers=2)
    pos = rng.uniform(-1.5, 1.5, (30, 2))
    for f in range(15):
        pos += rng.normal(0, 0.01, pos.shape)
        xy = pos + rng.normal(0, 0.005, pos.shape)
        obs = np.sort(rng.integers(0, 2, pos.shape[0]))
        sc = np.where(rng.random(pos.shape[0]) < 0.3, rng.uniform(0.1, 1.0, pos.shape[0]), 0.05)
        counts = rng.integers(0, 7, pos.shape[0])
        counts[[0, 7, -1]] = 0
        own = np.repeat(np.arange(pos.shape[0]), counts)
        a = rng.uniform(0, 6.3, own.size)
        pts = xy[own] + 0.035 * np.c_[np.cos(a), np.sin(a)]
        if f % 3 == 1:
            order = rng.permutation(own.size)
            pts, own = pts[order], own[order]
        delta = rng.normal(0, 0.01, (2, 3))
        fused.update_batch(obs, xy, sc, delta, DT, pts, own)
        staged.update_batch(obs, xy, sc, delta, DT, pts, own)
        for name in KinTracker._FIELDS:
            assert np.array_equal(getattr(fused, name), getattr(staged, name)), (f, name)
    assert len(fused) > 5 and (np.count_nonzero(fused._res_dof) > 3) == bool(pr.frame_residuals)


def test_frame_residuals_off_leave_resid_z_at_zero_and_a_fit_drops_that_input():
    """``frame_residuals=0``: no per-frame residuals (``resid_z`` reads 0, everything else as with them on);
    ``TrackKinModel.fit`` gives an input that is constant over its rows first-layer weights of exactly 0,
    so that the compiled decision skips it (and still equals the model's ``kin_prob``); bad values raise."""
    frames = list(_crowded_frames(3, n_frames=10))
    on, off = KinTracker(n_observers=3), KinTracker(TrackerParams(frame_residuals=0), n_observers=3)
    for obs, xy, sc, delta, pts, own in frames:
        on.update_batch(obs, xy, sc, delta, DT, pts, own)
        off.update_batch(obs, xy, sc, delta, DT, pts, own)
    assert np.count_nonzero(on._res_dof) > 5 and not np.any(off._res_dof) and not np.any(off._res_chi2)
    for name in KinTracker._FIELDS:  # the residuals touch nothing else
        if name not in ("_res_dof", "_res_chi2"):
            assert np.array_equal(getattr(on, name), getattr(off, name)), name
    i = TRACK_FEATURES.index("resid_z")
    f_on, f_off = on.track_features(1)["features"], off.track_features(1)["features"]
    assert np.all(f_off[:, i] == 0) and np.any(f_on[:, i] != 0)
    assert np.array_equal(np.delete(f_on, i, 1), np.delete(f_off, i, 1))
    rng = np.random.default_rng(0)
    X = rng.normal(0, 1, (300, len(TRACK_FEATURES)))
    X[:, i] = 0.0
    y = (X[:, 0] > 0).astype(float)
    m = TrackKinModel.fit(X, y, hidden=(4,), max_iter=40)
    assert np.all(m.layers[0][0][i] == 0) and np.all(np.abs(np.delete(m.layers[0][0], i, 0)).sum(1) > 0)
    m = TrackKinModel(rng.normal(0, 0.5, len(TRACK_FEATURES)), m.scale, m.layers, hit_only=True)
    tr = KinTracker(TrackerParams(frame_residuals=0), n_observers=3, kin_model=m)
    for obs, xy, sc, delta, pts, own in frames:
        tr.update_batch(obs, xy, sc, delta, DT, pts, own)
        tr.track_arrays(8)  # the decision in the next update's call
        rows, kp = tr._decide()
        assert np.array_equal(kp, m.kin_prob(tr._features_fast(rows)))
    with pytest.raises(ValueError, match="frame_residuals"):
        TrackerParams(frame_residuals=2)
    with pytest.raises(ValueError, match="resid_clamp"):
        TrackerParams(frame_residuals=0, resid_clamp=2.0)


def test_slots_filled_in_the_update_call_equal_track_arrays_own():
    """When the last frame's outputs were read, the update's call fills ``track_arrays``' slots too (as many
    as that read asked for): the first read of the frame returns them, a second read of the same frame builds
    its own arrays (not the same objects: a caller may write into them) with the same values, and a read with
    another ``max_tracks`` builds them afresh; a tracker read only now and then gives the same values."""
    frames = list(_crowded_frames(21, n_obs=3, n_frames=14))
    tr, lazy = KinTracker(n_observers=3), KinTracker(n_observers=3)
    fused = 0
    for f, (obs, xy, sc, delta, pts, own) in enumerate(frames):
        for t in (tr, lazy):
            t.update_batch(obs, xy, sc, delta, DT, pts, own, accepted=sc > 0.5)
        n = 4 if f < 9 else 6  # the slot count changes once: that frame's read builds its own
        fused += tr._pending_slots is not None and tr._pending_slots[1] == n
        a, b = tr.track_arrays(n), tr.track_arrays(n)
        assert all(a[k] is not b[k] and np.array_equal(a[k], b[k]) for k in ("tracks", "mask", "count"))
        if f % 4 == 3:  # the lazy tracker reads some frames only: computed afresh
            c = lazy.track_arrays(n)
            assert all(np.array_equal(a[k], c[k]) for k in ("tracks", "mask", "count"))
        assert a["tracks"].shape == (3, n, len(TRACK_FIELDS))
    assert fused == len(frames) - 2  # every frame but the first and the one whose slot count changed


def test_track_block_is_the_slots_transposed_and_filled_in_the_update():
    """The envs' info block (``_track_block``, read every frame as an env reads it): filled in the update's
    compiled call from the second frame on, bitwise ``track_arrays(n)["tracks"].transpose(2, 0, 1)
    .astype(float64)`` of a tracker read through ``track_arrays`` (same state, same later reads), each field a
    C-contiguous row; a ``track_arrays`` read of the same frame afterwards gives that tracker's arrays, a
    different slot count or a hand-tuned tracker (no decision in the update) builds the block afresh."""
    for kin_model in ("learned", "hand"):
        frames = list(_crowded_frames(5, n_obs=3, n_frames=14))
        tr, ref = (KinTracker(n_observers=3, kin_model=kin_model) for _ in range(2))
        fused = 0
        for f, (obs, xy, sc, delta, pts, own) in enumerate(frames):
            for t in (tr, ref):
                t.update_batch(obs, xy, sc, delta, DT, pts, own, accepted=sc > 0.5)
            n = 4 if f < 9 else 6
            fused += tr._pending_slots is not None and tr._pending_slots[1:3] == (n, True)
            block, count = tr._track_block(n)
            a = ref.track_arrays(n)
            want = a["tracks"].transpose(2, 0, 1).astype(np.float64, order="C")
            assert block.dtype == np.float64 and block.flags.c_contiguous and block.shape == (10, 3, n)
            assert block.tobytes() == want.tobytes() and count.tobytes() == a["count"].tobytes()
            if f % 3 == 2:  # a second read of the frame: the same arrays as the reference tracker's
                b = tr.track_arrays(n)
                assert all(np.array_equal(b[k], ref.track_arrays(n)[k]) for k in ("tracks", "mask", "count"))
            assert all(tr.kin_prob(o).tobytes() == ref.kin_prob(o).tobytes() for o in range(3))
        for name in ("_F", "_I", "_B", *KinTracker._FIELDS):
            assert np.asarray(getattr(tr, name)).tobytes() == np.asarray(getattr(ref, name)).tobytes(), name
        # every frame but the first and the one whose slot count changed (the first read of a frame sets the
        # form the next update fills: a track_arrays read after the block changes nothing)
        assert fused == (len(frames) - 2 if kin_model == "learned" else 0)
    with pytest.raises(ValueError, match="max_tracks must be an int >= 0"):
        tr._track_block(-1)
