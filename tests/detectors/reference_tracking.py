"""The tracker as it was before the fused frame update, as test references:

* :class:`StagedKinTracker`: the frame update as a sequence of Python steps calling the compiled stage
  kernels (predict / gate / assign / update / birth, score cue, outline and per-frame fits, classifier
  inputs, existence / motion / confirm / delete), which :func:`detectors.tracking._update_kernel` now runs
  in one call: the fused tracker must reproduce it bitwise. Where a stage kernel was made faster since,
  the staged tracker keeps its previous version as the oracle: the association and the existence step
  (``_frame_kernel_before``, ``_finish_kernel_before``, below) and the per-frame circle fits one at a
  time (:meth:`StagedKinTracker._frame_fits`);
* :class:`ReferenceKinTracker`: the staged tracker with the frame steps and score cue in numpy (one array
  operation per step), as before the compiled kernels: the compiled tracker must give the same tracks."""

import math

import numba
import numpy as np
from scipy.optimize import linear_sum_assignment

from detectors.base import wrap_angle
from detectors.tracking import (
    TRACK_FIELDS,
    KinTracker,
    _feature_kernel,
    _fit_known_circle,
    _kalman_update,
    _logit,
    _outline_kernel,
    _points_check,
    _points_prep,
    _score_kernel,
    _score_logits,
)


class StagedKinTracker(KinTracker):
    """:class:`KinTracker` with the frame update as separate steps (the overridable methods below)."""

    def update_batch(
        self, obs, xy, scores, odom_delta, dt: float, points=None, owner=None, noise=None, accepted=None
    ) -> None:
        """:meth:`KinTracker.update_batch` (same arguments), one overridable step after another."""
        pr, N = self.params, self.n_observers
        obs = np.asarray(obs).reshape(-1)
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        scores = np.asarray(scores, dtype=np.float64).reshape(-1)
        delta = np.asarray(odom_delta, dtype=np.float64)
        k = xy.shape[0]
        if delta.shape != (N, 3) or not np.all(np.isfinite(delta)):
            raise ValueError(
                f"KinTracker: odom_delta must be ({N}, 3) finite numbers (dx, dy, dtheta per observer), "
                f"got {np.shape(odom_delta)} {odom_delta!r}"
            )
        if not (isinstance(dt, int | float) and math.isfinite(dt) and dt > 0):
            raise ValueError(f"KinTracker: dt must be a positive number of seconds, got {dt!r}")
        if (
            scores.shape[0] != k
            or obs.shape[0] != k
            or not (np.all(np.isfinite(xy)) and np.all(np.isfinite(scores)))
        ):
            raise ValueError(
                f"KinTracker: obs (k,), xy (k, 2) and scores (k,) must be finite and of one length, got "
                f"{obs.shape}, {xy.shape} and {scores.shape}"
            )
        if k and (not np.issubdtype(obs.dtype, np.integer) or obs.min() < 0 or obs.max() >= N):
            raise ValueError(f"KinTracker: obs must be observer indices in [0, {N}), got {obs!r}")
        noise = np.full(N, pr.range_noise) if noise is None else np.asarray(noise, np.float64).reshape(-1)
        if noise.shape != (N,) or not np.all(np.isfinite(noise) & (noise >= 0)):
            raise ValueError(f"KinTracker: noise must be {N} relative range noises >= 0, got {noise!r}")
        obs = obs.astype(np.int64)
        if accepted is not None:
            accepted = np.asarray(accepted, dtype=bool).reshape(-1)
            if accepted.shape[0] != k:
                raise ValueError(
                    f"KinTracker: accepted must have one flag per candidate ({k}), got {accepted.shape}"
                )
        if k and pr.min_score > 0:
            keep = scores >= pr.min_score
            if not keep.all():
                if points is not None:  # renumber the kept candidates' points
                    owner = np.asarray(owner).reshape(-1).astype(np.int64)
                    new = np.cumsum(keep) - 1
                    sel = keep[owner] if owner.size else np.zeros(0, bool)
                    points = np.asarray(points, np.float64).reshape(-1, 2)[sel]
                    owner = new[owner[sel]]
                obs, xy, scores = obs[keep], xy[keep], scores[keep]
                accepted = None if accepted is None else accepted[keep]
                k = xy.shape[0]
        # ego-motion: each observer's new pose in its odometry frame
        c, s = np.cos(self.poses[:, 2]), np.sin(self.poses[:, 2])
        self.poses = np.c_[
            self.poses[:, 0] + c * delta[:, 0] - s * delta[:, 1],
            self.poses[:, 1] + s * delta[:, 0] + c * delta[:, 1],
            wrap_angle(self.poses[:, 2] + delta[:, 2]),
        ]
        self.time += dt
        # each wheel's travel: ego-motion errors grow with it (the odometry error model's random walk)
        half_turn = 0.5 * self.params.wheel_base * np.abs(delta[:, 2])
        self.odometer += np.hypot(delta[:, 0], delta[:, 1]) + half_turn
        cos, sin = np.cos(self.poses[:, 2]), np.sin(self.poses[:, 2])
        z = self._to_odom(xy, obs, cos, sin)  # candidates in their observer's odometry frame
        rng = np.sqrt(xy[:, 0] * xy[:, 0] + xy[:, 1] * xy[:, 1])
        if int(self._alive.sum()) + k > self._alive.shape[0]:  # room for every candidate to start a track
            self._grow(int(self._alive.sum()) + k)
        pre = self._alive.copy()  # the tracks before this frame's births (existence: hit or miss)
        ti, ci, tb, born = self._associate_and_birth(
            z, obs, rng, dt, (scores >= self.params.birth_min_score) | (self.params.birth_min_score <= 0)
        )
        tracks, cands = np.concatenate([ti, tb]), np.concatenate([ci, born])
        self._score_cue(tracks, scores[cands], None if accepted is None else accepted[cands], rng[cands])
        beams = np.zeros(k)
        if points is not None and len(tracks):
            self._outline_cue(tracks, cands, points, owner, obs, noise, cos, sin, k, z, xy)  # validates owner
            beams = np.bincount(np.asarray(owner, np.int64).reshape(-1), minlength=k).astype(np.float64)
        _feature_kernel(tracks, len(ti), _score_logits(scores[cands]),
                        np.zeros(0, np.bool_) if accepted is None else accepted[cands], rng[cands],
                        beams[cands], self._f_lgsum, self._f_lgsq, self._f_lgmax, self._f_lglast,
                        self._f_accsum, self._f_acclast, self._f_beams, self._f_rng, self._hit)  # fmt: skip
        hit = np.zeros(self._alive.shape[0], bool)
        hit[ti] = True
        self._finish(pre, hit, dt)

    def _to_odom(self, xy, obs, cos, sin) -> np.ndarray:
        c, s, p = cos[obs], sin[obs], self.poses[obs]
        out = np.empty((xy.shape[0], 2))
        out[:, 0] = c * xy[:, 0] - s * xy[:, 1] + p[:, 0]
        out[:, 1] = s * xy[:, 0] + c * xy[:, 1] + p[:, 1]
        return out

    def _meas_var(self, rng: np.ndarray) -> np.ndarray:
        return (self.params.meas_sigma + self.params.meas_sigma_rel * rng) ** 2

    def _associate_and_birth(self, z, obs, rng, dt, birth_ok):
        """Predict, gate, assign, Kalman-update and start tracks for unmatched candidates where ``birth_ok``
        (one compiled kernel). Returns (matched track rows, their candidates, born track rows, their
        candidates)."""
        pr = self.params
        ti, ci, tb, born, next_id = _frame_kernel_before(
            np.ascontiguousarray(z), obs, rng, float(dt), self.n_observers, self._alive, self._obs, self._id,
            self._next_id, self._x, self._P, self.poses, self._exist, self._lo_score, self._lo_shape,
            self._lo_motion, self._lo_resid, self._res_chi2, self._res_dof, self._score_sum, self._n_scored,
            self._seen, self._age, self._static_t, self._moved, self._confirmed, self._npts, self._head,
            self._fit_c, self._anchor, self._anchor_var, self._anchor_odo, self._anchor_rng, self.odometer,
            pr.process_accel**2, pr.meas_sigma, pr.meas_sigma_rel, pr.init_speed_sigma**2, pr.gate_chi2,
            pr.birth_existence, pr.confirm_existence, pr.r, birth_ok,
        )  # fmt: skip
        self._next_id = int(next_id)
        return ti, ci, tb, born

    def _finish(self, pre, hit, dt) -> None:
        """Existence (hit / miss of the tracks before this frame's births), motion, age, confirm / delete."""
        pr = self.params
        _finish_kernel_before(
            pre, hit, float(dt), self._alive, self._obs, self._x, self._P, self.poses, self._exist,
            self._confirmed, self._moved, self._lo_motion, self._static_t, self._age, self._seen,
            self._anchor, self._anchor_var, self._anchor_odo, self._anchor_rng, self.odometer, pr.p_detect,
            pr.clutter_ratio, pr.max_range, pr.confirm_existence, pr.delete_existence, pr.motion_dist,
            pr.motion_gain, pr.odom_heading_rate**2, pr.odom_position_rate**2,
        )  # fmt: skip

    def _score_cue(self, ti: np.ndarray, scores: np.ndarray, accepted, rng: np.ndarray) -> None:
        # (a) the detector's score: correlated frames -> weight < 1, clamped sum
        pr = self.params
        # a far object gets fewer beams and lower scores, kin and look-alikes alike: the bar falls with range.
        # The cue is the mean evidence per frame (shrunk towards 0 by score_n0 pseudo-frames) times
        # score_gain: frames of one object are strongly correlated, so the evidence grows with their
        # consistency, not their count (one compiled loop over the updated tracks)
        acc = np.zeros(0, np.bool_) if accepted is None else np.asarray(accepted, np.bool_)
        _score_kernel(ti, _score_logits(np.asarray(scores, np.float64)), acc, rng, self._score_sum,
                      self._n_scored, self._lo_score, float(_logit(pr.score_prior)), pr.score_per_metre,
                      pr.score_weight, pr.accept_llr, pr.reject_llr, pr.score_n0, pr.score_gain,
                      pr.score_clamp)  # fmt: skip

    def _outline_cue(self, ti, ci, points, owner, obs, noise, cos, sin, k, z, xy) -> None:
        # (b) the accumulated outline relative to the track centre (ego-motion compensated)
        pr = self.params
        pts = np.asarray(points, np.float64).reshape(-1, 2)
        owner = np.asarray(owner).reshape(-1).astype(np.int64)
        pts = np.ascontiguousarray(pts)
        status = _points_check(pts, owner, k) if owner.shape[0] == pts.shape[0] else 1
        if status == 1:
            raise ValueError(
                f"KinTracker: owner must give each of the {pts.shape[0]} points a candidate in [0, {k})"
            )
        if status == 2:
            raise ValueError("KinTracker: points must be finite")
        if status == 3:  # not grouped by candidate (segment_points gives them sorted already)
            order = np.argsort(owner, kind="stable")
            pts, owner = np.ascontiguousarray(pts[order]), owner[order]
        cstart = np.searchsorted(owner, np.arange(k + 1))
        centre = pr.frame_fit_warm_start == 1  # from the candidate's own centre: in the robot frame
        if centre and pr.frame_residuals:
            self._centre_resid(ti, ci, pts, cstart, xy, obs, noise)
        ring = self._pts.shape[1] > 0  # the outline's points kept (its cue on, or keep_points)
        if centre and not ring:
            return  # nothing reads the odometry-frame points
        odom, sig, d = _points_prep(pts, owner, obs, noise, cos, sin, self.poses,
                                    pr.shape_sigma**2)  # fmt: skip
        if not centre and pr.frame_residuals:
            self._frame_fits(ti, ci, odom, sig, cstart, z)
        if not ring:
            return
        _outline_kernel(
            ti, ci, odom, sig, d, cstart, self._obs, self.odometer, self._moved,
            self._pts, self._pts_aux, self._npts, self._head, self._fit_c, self._lo_shape, self._x, self._P,
            self.time,
            pr.r, pr.shape_delta**2, float(pr.shape_n_cap), int(pr.shape_min_points),
            pr.shape_clamp, pr.odom_heading_rate**2, pr.odom_position_rate**2,
        )  # fmt: skip

    def _centre_resid(self, ti, ci, pts, cstart, xy, obs, noise) -> None:
        """The residual sums without a fit, in Python (the oracle of
        :func:`detectors.tracking._centre_resid_kernel`): each candidate's points (robot frame, 3 or more)
        against the housing circle at its own centre, variance ``shape_sigma^2 + (noise * range)^2``."""
        pr = self.params
        r, s2, delta2, clamp = pr.r, pr.shape_sigma**2, pr.shape_delta**2, pr.resid_clamp
        for t, c in zip(ti.tolist(), ci.tolist(), strict=True):
            a, b = int(cstart[c]), int(cstart[c + 1])
            mf = b - a
            if mf < 3:
                continue
            n2 = float(noise[obs[c]]) * float(noise[obs[c]])
            # Gauss-Newton steps from the candidate's centre (frame_fit_iterations), as _fit_span's
            cx, cy = float(xy[c, 0]), float(xy[c, 1])
            for _ in range(int(pr.frame_fit_iterations)):
                A = np.zeros((2, 2))
                g = np.zeros(2)
                for p in range(a, b):
                    px, py = float(pts[p, 0]), float(pts[p, 1])
                    w = 1.0 / (s2 + n2 * (px * px + py * py))
                    d = max(math.sqrt((px - cx) * (px - cx) + (py - cy) * (py - cy)), 1e-12)
                    inv = 1.0 / d
                    jac = np.array([-(px - cx) * inv, -(py - cy) * inv])
                    A[0, 0] += w * jac[0] * jac[0]
                    A[0, 1] += w * jac[0] * jac[1]
                    A[1, 1] += w * jac[1] * jac[1]
                    g += w * jac * (d - r)
                det = A[0, 0] * A[1, 1] - A[0, 1] * A[0, 1]
                if det <= 1e-12 * (A[0, 0] + A[1, 1]) ** 2:
                    break
                s0 = -(A[1, 1] * g[0] - A[0, 1] * g[1]) / det
                s1 = -(A[0, 0] * g[1] - A[0, 1] * g[0]) / det
                cx, cy = cx + s0, cy + s1
                if s0 * s0 + s1 * s1 < 1e-18:
                    break
            chi2 = llr = 0.0
            for p in range(a, b):
                px, py = float(pts[p, 0]), float(pts[p, 1])
                v0 = s2 + n2 * (px * px + py * py)
                e = math.sqrt((px - cx) * (px - cx) + (py - cy) * (py - cy)) - r
                chi2 += e * e * (1.0 / v0)  # the weight, 1 / variance
                if clamp > 0.0:
                    v1 = v0 + delta2
                    llr += 0.5 * math.log(v1 / v0) * (mf - 2) / mf - 0.5 * e * e * (1.0 / v0 - 1.0 / v1)
            self._res_chi2[t] += chi2
            self._res_dof[t] += mf - 2
            if clamp > 0.0:
                self._lo_resid[t] = min(max(self._lo_resid[t] + llr, -clamp), clamp)

    def _frame_fits(self, ti, ci, pts, sig, cstart, z) -> None:
        """The per-frame circle fits one at a time, as before they ran eight to a vector
        (:func:`detectors.tracking._frame_fits_kernel`): the start, :func:`_fit_known_circle` and the
        residual sums, in Python."""
        pr = self.params
        r, delta2, clamp = pr.r, pr.shape_delta**2, pr.resid_clamp
        for t, c in zip(ti.tolist(), ci.tolist(), strict=True):
            a, b = int(cstart[c]), int(cstart[c + 1])
            mf = b - a
            if mf < 3:
                continue
            mx = my = 0.0
            for p in range(a, b):
                mx += pts[p, 0]
                my += pts[p, 1]
            w = np.array([1.0 / (sig[p] * sig[p]) for p in range(a, b)])
            mx /= mf
            my /= mf
            pose = self.poses[self._obs[t]]
            ux, uy = mx - pose[0], my - pose[1]
            un = max(math.sqrt(ux * ux + uy * uy), 1e-9)
            cen = np.array([mx + ux / un * r * 0.7, my + uy / un * r * 0.7])
            if pr.frame_fit_warm_start:
                cen = z[c].copy()
            e = np.empty(mf)
            _fit_known_circle(np.ascontiguousarray(pts[a:b]), w, r, cen, int(pr.frame_fit_iterations), e)
            llr = chi2 = 0.0
            for p in range(a, b):
                v0 = sig[p] * sig[p]
                v1 = v0 + delta2
                ee = e[p - a] * e[p - a]
                chi2 += ee / v0
                if clamp > 0.0:
                    llr += 0.5 * math.log(v1 / v0) * (mf - 2) / mf - 0.5 * ee * (1.0 / v0 - 1.0 / v1)
            self._res_chi2[t] += chi2
            self._res_dof[t] += mf - 2
            if clamp > 0.0:
                self._lo_resid[t] = min(max(self._lo_resid[t] + llr, -clamp), clamp)

    def _features_fast(self, rows):  # the numpy features
        return self._features(rows)

    def track_arrays(self, max_tracks: int) -> dict[str, np.ndarray]:
        """Fixed-shape view for vector envs: ``tracks`` (n_observers, max_tracks, len(TRACK_FIELDS)) float32,
        zero-padded (columns :data:`TRACK_FIELDS`; positions and velocities in each observer's current robot
        frame), ``mask`` (n_observers, max_tracks) bool and ``count`` (n_observers,). Per observer, confirmed
        tracks come first, then by kin probability, when there are more than ``max_tracks``."""
        N = self.n_observers
        out = np.zeros((N, max_tracks, len(TRACK_FIELDS)), np.float32)
        mask = np.zeros((N, max_tracks), bool)
        rows = np.flatnonzero(self._alive)
        if rows.size:
            kp = self._kin_prob(rows)
            o = self._obs[rows]
            order = np.lexsort((self._id[rows], -(kp + self._confirmed[rows]), o))
            rows, kp, o = rows[order], kp[order], o[order]
            n_o = np.bincount(o, minlength=N)
            rank = np.arange(rows.size) - np.repeat(np.cumsum(n_o) - n_o, n_o)
            keep = rank < max_tracks
            rows, kp, o, rank = rows[keep], kp[keep], o[keep], rank[keep]
            pose = self.poses[o]
            c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
            d = self._x[rows, :2] - pose[:, :2]
            v = self._x[rows, 2:]
            cols = np.stack(
                [self._id[rows], c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1],
                 c * v[:, 0] + s * v[:, 1], -s * v[:, 0] + c * v[:, 1], self._exist[rows], kp,
                 self._seen[rows], self._confirmed[rows], self._age[rows]], axis=1,
            )  # fmt: skip
            out[o, rank] = cols
            mask[o, rank] = True
        count = mask.sum(axis=1).astype(np.int64)
        return {"tracks": out, "mask": mask, "count": count}


class ReferenceKinTracker(StagedKinTracker):
    """:class:`KinTracker` with the numpy steps (predict, gate, Hungarian, Kalman update, birth,
    existence, motion, confirm / delete)."""

    def _associate_and_birth(self, z, obs, rng, dt, birth_ok):
        rows = np.flatnonzero(self._alive)
        self._predict(rows, dt)
        ti, ci = self._associate(rows, z, obs, rng)
        self._kalman_update(ti, z[ci], rng[ci])
        born = np.setdiff1d(np.arange(z.shape[0]), ci, assume_unique=True)
        born = born[birth_ok[born]]
        tb = self._birth(z[born], obs[born], rng[born])
        return ti, ci, tb, born

    def _finish(self, pre, hit, dt):
        pr = self.params
        rows = np.flatnonzero(pre)
        self._existence(rows, hit[rows])
        rows = np.flatnonzero(self._alive)
        self._motion(rows, dt)
        self._age[rows] += 1
        self._alive[rows] = self._exist[rows] >= pr.delete_existence

    def _predict(self, rows: np.ndarray, dt: float) -> None:
        if not rows.size:
            return
        F = np.eye(4)
        F[0, 2] = F[1, 3] = dt
        q = self.params.process_accel**2
        Q1 = q * np.array([[dt**4 / 4, dt**3 / 2], [dt**3 / 2, dt**2]])
        Q = np.zeros((4, 4))
        Q[np.ix_([0, 2], [0, 2])] = Q1
        Q[np.ix_([1, 3], [1, 3])] = Q1
        self._x[rows] = self._x[rows] @ F.T
        self._P[rows] = F @ self._P[rows] @ F.T + Q

    def _associate(self, rows, z, obs, rng) -> tuple[np.ndarray, np.ndarray]:
        """(track rows, candidate indices) of each observer's jointly optimal gated assignment."""
        none = np.zeros(0, np.int64)
        if not rows.size or not z.shape[0]:
            return none, none
        # every (track, candidate) pair of the same observer
        order = np.argsort(self._obs[rows], kind="stable")
        trk = rows[order]
        n_t = np.bincount(self._obs[trk], minlength=self.n_observers)
        start = np.cumsum(n_t) - n_t
        per_c = n_t[obs]
        if not per_c.sum():
            return none, none
        cand = np.repeat(np.arange(z.shape[0]), per_c)
        within = np.arange(cand.size) - np.repeat(np.cumsum(per_c) - per_c, per_c)
        tr = trk[start[obs[cand]] + within]
        S = self._P[tr, :2, :2] + np.eye(2) * self._meas_var(rng[cand])[:, None, None]
        d = z[cand] - self._x[tr, :2]
        det = S[:, 0, 0] * S[:, 1, 1] - S[:, 0, 1] * S[:, 1, 0]
        m2 = (
            S[:, 1, 1] * d[:, 0] ** 2 - 2 * S[:, 0, 1] * d[:, 0] * d[:, 1] + S[:, 0, 0] * d[:, 1] ** 2
        ) / det
        ok = m2 <= self.params.gate_chi2
        tr, cand, m2 = tr[ok], cand[ok], m2[ok]
        if not tr.size:
            return none, none
        # a pair whose track and candidate are in no other gate is forced; the rest is solved per observer
        cap = self._alive.shape[0]
        forced = (np.bincount(tr, minlength=cap)[tr] == 1) & (
            np.bincount(cand, minlength=z.shape[0])[cand] == 1
        )
        ti, ci = [tr[forced]], [cand[forced]]
        amb = ~forced
        for o in np.unique(obs[cand[amb]]):
            sel = amb & (obs[cand] == o)
            ut, t_inv = np.unique(tr[sel], return_inverse=True)
            uc, c_inv = np.unique(cand[sel], return_inverse=True)
            cost = np.full((ut.size, uc.size), 1e6)
            cost[t_inv, c_inv] = m2[sel]
            r, c = linear_sum_assignment(cost)
            keep = cost[r, c] < 1e6
            ti.append(ut[r[keep]])
            ci.append(uc[c[keep]])
        return np.concatenate(ti).astype(np.int64), np.concatenate(ci).astype(np.int64)

    def _kalman_update(self, ti: np.ndarray, z: np.ndarray, rng: np.ndarray) -> None:
        """Batched Kalman update of tracks ``ti`` with candidates ``z`` (Joseph form)."""
        if not ti.size:
            return
        x, P = self._x[ti], self._P[ti]
        Rm = np.eye(2) * self._meas_var(rng)[:, None, None]  # (m, 2, 2)
        S = P[:, :2, :2] + Rm
        K = P[:, :, :2] @ np.linalg.inv(S)  # (m, 4, 2)
        x += np.einsum("mij,mj->mi", K, z - x[:, :2])
        IKH = np.broadcast_to(np.eye(4), P.shape).copy()
        IKH[:, :, :2] -= K
        self._P[ti] = IKH @ P @ IKH.transpose(0, 2, 1) + K @ Rm @ K.transpose(0, 2, 1)
        self._x[ti] = x
        self._seen[ti] += 1

    def _birth(self, z: np.ndarray, obs: np.ndarray, rng: np.ndarray) -> np.ndarray:
        """Start tentative tracks at candidates ``z`` (k, 2) of observers ``obs``; returns their rows."""
        k, pr = z.shape[0], self.params
        free = np.flatnonzero(~self._alive)
        if free.size < k:
            self._grow(self._alive.shape[0] + k)
            free = np.flatnonzero(~self._alive)
        ti = free[:k]
        self._alive[ti] = True
        self._id[ti] = np.arange(self._next_id, self._next_id + k)
        self._next_id += k
        self._obs[ti] = obs
        var = self._meas_var(rng)
        self._x[ti] = np.c_[z, np.zeros((k, 2))]
        self._P[ti] = 0.0
        self._P[ti, 0, 0] = self._P[ti, 1, 1] = var
        self._P[ti, 2, 2] = self._P[ti, 3, 3] = pr.init_speed_sigma**2
        self._exist[ti] = pr.birth_existence
        self._lo_score[ti] = self._lo_shape[ti] = self._lo_motion[ti] = 0.0
        self._lo_resid[ti] = self._res_chi2[ti] = self._res_dof[ti] = 0.0
        self._score_sum[ti] = self._n_scored[ti] = 0.0
        self._seen[ti] = 1
        self._age[ti] = 0
        self._static_t[ti] = 0.0
        self._moved[ti] = False
        self._confirmed[ti] = pr.birth_existence >= pr.confirm_existence
        self._npts[ti] = self._head[ti] = 0
        # the housing's centre is r behind the visible arc's middle, seen from the observer
        away = z - self.poses[obs, :2]
        self._fit_c[ti] = z + away / np.maximum(np.hypot(away[:, 0], away[:, 1]), 1e-9)[:, None] * pr.r * 0.5
        self._anchor[ti] = z
        self._anchor_var[ti] = var
        self._anchor_odo[ti] = self.odometer[obs]
        self._anchor_rng[ti] = rng
        return ti

    def _existence(self, rows: np.ndarray, hit: np.ndarray) -> None:
        pr = self.params
        p = self._exist[rows]
        in_range = np.hypot(*(self._x[rows, :2] - self.poses[self._obs[rows], :2]).T) <= pr.max_range
        p_hit = p / (p + (1 - p) * pr.clutter_ratio)
        p_miss = p * (1 - pr.p_detect) / (1 - p * pr.p_detect)
        self._exist[rows] = np.where(hit, p_hit, np.where(in_range, p_miss, p))
        alive = np.flatnonzero(self._alive)
        self._confirmed[alive] |= self._exist[alive] >= pr.confirm_existence

    def _motion(self, rows: np.ndarray, dt: float) -> None:
        pr = self.params
        if not rows.size:
            return
        disp = np.hypot(*(self._x[rows, :2] - self._anchor[rows]).T)
        # odometry drift makes static objects slide in the odometry frame: allow for it
        aged = self.odometer[self._obs[rows]] - self._anchor_odo[rows]
        drift = aged * (pr.odom_heading_rate**2 * self._anchor_rng[rows] ** 2 + pr.odom_position_rate**2)
        var = self._anchor_var[rows] + 0.5 * (self._P[rows, 0, 0] + self._P[rows, 1, 1]) + drift
        moving = (disp > pr.motion_dist) & (disp > 3.0 * np.sqrt(var)) & (self._seen[rows] > 2)
        self._moved[rows] |= moving
        self._lo_motion[rows] = np.where(self._moved[rows], pr.motion_gain, 0.0)
        self._static_t[rows] += dt

    def _score_cue(self, ti, scores, accepted, rng):
        pr = self.params
        logit = lambda p: np.log(np.clip(p, 1e-6, 1 - 1e-6) / (1 - np.clip(p, 1e-6, 1 - 1e-6)))  # noqa: E731
        bar = logit(pr.score_prior) - pr.score_per_metre * (rng - 1.0)
        step = pr.score_weight * (np.clip(logit(scores), -6.0, 6.0) - bar)
        if accepted is not None:
            step = step + np.where(accepted, pr.accept_llr, pr.reject_llr)
        self._score_sum[ti] += step
        self._n_scored[ti] += 1
        mean = self._score_sum[ti] / (self._n_scored[ti] + pr.score_n0)
        self._lo_score[ti] = np.clip(pr.score_gain * mean, -pr.score_clamp, pr.score_clamp)

# -- the frame kernels as they were before the association's spatial pruning and the existence step's
# pre-checks (the fused update must reproduce them bit for bit) ---------------------------------------------


@numba.njit(cache=True, nogil=True)
def _find_before(parent, i):
    """Union-find root of ``i`` (with path halving)."""
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@numba.njit(cache=True, nogil=True)
def _hungarian_before(cost):
    """Minimum-cost assignment of the rows of ``cost`` (n, m), n <= m, to distinct columns (shortest
    augmenting paths with potentials, O(n^2 m)); returns each row's column."""
    n, m = cost.shape
    inf = 1e300
    u = np.zeros(n + 1)
    v = np.zeros(m + 1)
    p = np.zeros(m + 1, np.int64)
    way = np.zeros(m + 1, np.int64)
    minv = np.empty(m + 1)
    used = np.empty(m + 1, np.bool_)
    for i in range(1, n + 1):
        p[0] = i
        j0 = 0
        minv[:] = inf
        used[:] = False
        while True:
            used[j0] = True
            i0 = p[j0]
            delta = inf
            j1 = 0
            for j in range(1, m + 1):
                if not used[j]:
                    cur = cost[i0 - 1, j - 1] - u[i0] - v[j]
                    if cur < minv[j]:
                        minv[j] = cur
                        way[j] = j0
                    if minv[j] < delta:
                        delta = minv[j]
                        j1 = j
            for j in range(m + 1):
                if used[j]:
                    u[p[j]] += delta
                    v[j] -= delta
                else:
                    minv[j] -= delta
            j0 = j1
            if p[j0] == 0:
                break
        while True:
            j1 = way[j0]
            p[j0] = p[j1]
            j0 = j1
            if j0 == 0:
                break
    ans = np.full(n, -1, np.int64)
    for j in range(1, m + 1):
        if p[j] != 0:
            ans[p[j] - 1] = j - 1
    return ans


@numba.njit(cache=True, nogil=True)
def _frame_kernel_before(z, obs, rng, dt, n_obs, alive, tobs, tid, next_id, x, P, poses, exist, lo_score,
                         lo_shape, lo_motion, lo_resid, res_chi2, res_dof, score_sum, n_scored, seen, age,
                         static_t, moved, confirmed, npts, head, fit_c, anchor, anchor_var, anchor_odo,
                         anchor_rng, odometer, q, meas_sigma, meas_sigma_rel, speed_var, gate, birth_exist,
                         confirm_exist, r, birth_ok):  # fmt: skip
    """One frame's predict (constant velocity), Mahalanobis gating, assignment (a pair alone in both its
    gates is forced; the rest per observer by :func:`_hungarian`), Joseph-form Kalman update, and births."""
    cap = alive.shape[0]
    k = z.shape[0]
    # predict
    q11, q12, q22 = q * dt**4 / 4, q * dt**3 / 2, q * dt * dt
    for t in range(cap):
        if not alive[t]:
            continue
        x[t, 0] += dt * x[t, 2]
        x[t, 1] += dt * x[t, 3]
        # P <- F P F^T + Q with F = [[I, dt I], [0, I]]
        Pt = P[t]  # P F^T: columns 0, 1 += dt * columns 2, 3; then F (P F^T): rows likewise
        for i in range(4):
            Pt[i, 0] += dt * Pt[i, 2]
            Pt[i, 1] += dt * Pt[i, 3]
        for j in range(4):
            Pt[0, j] += dt * Pt[2, j]
            Pt[1, j] += dt * Pt[3, j]
        Pt[0, 0] += q11
        Pt[1, 1] += q11
        Pt[0, 2] += q12
        Pt[2, 0] += q12
        Pt[1, 3] += q12
        Pt[3, 1] += q12
        Pt[2, 2] += q22
        Pt[3, 3] += q22
    # group tracks and candidates by observer (stable counting sort)
    t_cnt = np.zeros(n_obs + 1, np.int64)
    c_cnt = np.zeros(n_obs + 1, np.int64)
    for t in range(cap):
        if alive[t]:
            t_cnt[tobs[t] + 1] += 1
    for c in range(k):
        c_cnt[obs[c] + 1] += 1
    for o in range(n_obs):
        t_cnt[o + 1] += t_cnt[o]
        c_cnt[o + 1] += c_cnt[o]
    t_ord = np.empty(t_cnt[n_obs], np.int64)
    c_ord = np.empty(k, np.int64)
    fill = t_cnt[:-1].copy()
    for t in range(cap):
        if alive[t]:
            t_ord[fill[tobs[t]]] = t
            fill[tobs[t]] += 1
    fill = c_cnt[:-1].copy()
    for c in range(k):
        c_ord[fill[obs[c]]] = c
        fill[obs[c]] += 1
    # gating: squared Mahalanobis distance under the innovation covariance
    n_pairs = 0
    for o in range(n_obs):
        n_pairs += (t_cnt[o + 1] - t_cnt[o]) * (c_cnt[o + 1] - c_cnt[o])
    pt = np.empty(n_pairs, np.int64)
    pc = np.empty(n_pairs, np.int64)
    pm = np.empty(n_pairs)
    deg_t = np.zeros(cap, np.int64)
    deg_c = np.zeros(k, np.int64)
    n_g = 0
    # a cheap bound first: m2 >= |d|^2 / lambda_max(S) with S = P_xy + mv I, so a pair whose |d|^2 exceeds
    # gate * lambda_max(S) (with a margin far above rounding) is outside the gate, and only the others need
    # the exact test (in a swarm most pairs of an observer are metres apart); the gated pairs are the same
    lam = np.empty(cap)
    for b in range(t_cnt[n_obs]):
        t = t_ord[b]
        h, off = 0.5 * (P[t, 0, 0] - P[t, 1, 1]), max(abs(P[t, 0, 1]), abs(P[t, 1, 0]))
        lam[t] = 0.5 * (P[t, 0, 0] + P[t, 1, 1]) + math.sqrt(h * h + off * off)
    gate_b = gate * (1.0 + 1e-6)
    for o in range(n_obs):
        for a in range(c_cnt[o], c_cnt[o + 1]):
            c = c_ord[a]
            mv = (meas_sigma + meas_sigma_rel * rng[c]) ** 2
            for b in range(t_cnt[o], t_cnt[o + 1]):
                t = t_ord[b]
                d0, d1 = z[c, 0] - x[t, 0], z[c, 1] - x[t, 1]
                if d0 * d0 + d1 * d1 > gate_b * (lam[t] + mv):
                    continue
                s00, s01, s10, s11 = P[t, 0, 0] + mv, P[t, 0, 1], P[t, 1, 0], P[t, 1, 1] + mv
                det = s00 * s11 - s01 * s10
                m2 = (s11 * d0 * d0 - 2 * s01 * d0 * d1 + s00 * d1 * d1) / det
                if m2 <= gate:
                    pt[n_g] = t
                    pc[n_g] = c
                    pm[n_g] = m2
                    deg_t[t] += 1
                    deg_c[c] += 1
                    n_g += 1
    ti = np.empty(min(n_g, k), np.int64)
    ci = np.empty(min(n_g, k), np.int64)
    n_m = 0
    # forced pairs; the rest of each observer's gated pairs (grouped by observer already) by the Hungarian
    t_loc = np.full(cap, -1, np.int64)
    c_loc = np.full(k, -1, np.int64)
    t_q = np.full(cap, -1, np.int64)
    c_q = np.full(k, -1, np.int64)
    a = 0
    while a < n_g:
        o = tobs[pt[a]]
        b = a
        while b < n_g and tobs[pt[b]] == o:
            b += 1
        nt = nc = 0
        for g in range(a, b):
            t, c = pt[g], pc[g]
            if deg_t[t] == 1 and deg_c[c] == 1:
                ti[n_m] = t
                ci[n_m] = c
                n_m += 1
            else:
                if t_loc[t] < 0:
                    t_loc[t] = nt
                    nt += 1
                if c_loc[c] < 0:
                    c_loc[c] = nc
                    nc += 1
        if nt:
            ut = np.empty(nt, np.int64)
            uc = np.empty(nc, np.int64)
            for g in range(a, b):
                if t_loc[pt[g]] >= 0:
                    ut[t_loc[pt[g]]] = pt[g]
                if c_loc[pc[g]] >= 0:
                    uc[c_loc[pc[g]]] = pc[g]
            # connected components of the ambiguous gates (tracks and candidates as nodes): the optimal
            # assignment (most pairs, then least cost) decomposes over them, so each is solved on its own
            # (in a swarm one observer's gates form many small clusters, not one big matrix)
            nn = nt + nc
            parent = np.arange(nn)
            for g in range(a, b):
                if not (deg_t[pt[g]] == 1 and deg_c[pc[g]] == 1):
                    u, v = _find_before(parent, t_loc[pt[g]]), _find_before(parent, nt + c_loc[pc[g]])
                    if u != v:
                        parent[u] = v
            comp = np.empty(nn, np.int64)
            cid = np.full(nn, -1, np.int64)
            n_comp = 0
            for i in range(nn):
                root = _find_before(parent, i)
                if cid[root] < 0:
                    cid[root] = n_comp
                    n_comp += 1
                comp[i] = cid[root]
            # pairs bucketed by component (counting sort)
            p_cnt = np.zeros(n_comp + 1, np.int64)
            for g in range(a, b):
                if not (deg_t[pt[g]] == 1 and deg_c[pc[g]] == 1):
                    p_cnt[comp[t_loc[pt[g]]] + 1] += 1
            for q in range(n_comp):
                p_cnt[q + 1] += p_cnt[q]
            p_ord = np.empty(p_cnt[n_comp], np.int64)
            fill = p_cnt[:-1].copy()
            for g in range(a, b):
                if not (deg_t[pt[g]] == 1 and deg_c[pc[g]] == 1):
                    q = comp[t_loc[pt[g]]]
                    p_ord[fill[q]] = g
                    fill[q] += 1
            for q in range(n_comp):
                # the component's tracks and candidates in ascending order (as np.unique in the reference)
                mt = mc = 0
                for z_ in range(p_cnt[q], p_cnt[q + 1]):
                    g = p_ord[z_]
                    if t_q[pt[g]] < 0:
                        t_q[pt[g]] = 0
                        mt += 1
                    if c_q[pc[g]] < 0:
                        c_q[pc[g]] = 0
                        mc += 1
                qt = np.empty(mt, np.int64)
                qc = np.empty(mc, np.int64)
                it = ic = 0
                for z_ in range(p_cnt[q], p_cnt[q + 1]):
                    g = p_ord[z_]
                    if t_q[pt[g]] == 0:
                        t_q[pt[g]] = 1
                        qt[it] = pt[g]
                        it += 1
                    if c_q[pc[g]] == 0:
                        c_q[pc[g]] = 1
                        qc[ic] = pc[g]
                        ic += 1
                qt.sort()
                qc.sort()
                for i in range(mt):
                    t_q[qt[i]] = i
                for i in range(mc):
                    c_q[qc[i]] = i
                cost = np.full((mt, mc), 1e6)
                for z_ in range(p_cnt[q], p_cnt[q + 1]):
                    g = p_ord[z_]
                    cost[t_q[pt[g]], c_q[pc[g]]] = pm[g]
                if mt <= mc:
                    col = _hungarian_before(cost)
                    for i in range(mt):
                        if col[i] >= 0 and cost[i, col[i]] < 1e6:
                            ti[n_m] = qt[i]
                            ci[n_m] = qc[col[i]]
                            n_m += 1
                else:
                    row = _hungarian_before(cost.T.copy())
                    for j in range(mc):
                        if row[j] >= 0 and cost[row[j], j] < 1e6:
                            ti[n_m] = qt[row[j]]
                            ci[n_m] = qc[j]
                            n_m += 1
                for i in range(mt):
                    t_q[qt[i]] = -1
                for i in range(mc):
                    c_q[qc[i]] = -1
            ut_s, uc_s = ut, uc
            for i in range(nt):
                t_loc[ut_s[i]] = -1
            for i in range(nc):
                c_loc[uc_s[i]] = -1
        a = b
    ti, ci = ti[:n_m], ci[:n_m]
    # the Kalman update (since session 14 the fused kernel's own, standard form: tested against filterpy)
    taken = np.zeros(k, np.bool_)
    for j in range(n_m):
        t, c = ti[j], ci[j]
        taken[c] = True
        _kalman_update(x[t], P[t], z[c, 0], z[c, 1], (meas_sigma + meas_sigma_rel * rng[c]) ** 2)
        seen[t] += 1
    # births: unmatched candidates (where birth_ok) in index order take the first free rows
    n_b = k - n_m
    for c in range(k):
        n_b -= not taken[c] and not birth_ok[c]
    born = np.empty(n_b, np.int64)
    tb = np.empty(n_b, np.int64)
    j = 0
    for c in range(k):
        if not taken[c] and birth_ok[c]:
            born[j] = c
            j += 1
    t = 0
    for j in range(n_b):
        while alive[t]:
            t += 1
        c = born[j]
        tb[j] = t
        alive[t] = True
        tid[t] = next_id
        next_id += 1
        o = obs[c]
        tobs[t] = o
        mv = (meas_sigma + meas_sigma_rel * rng[c]) ** 2
        x[t, 0], x[t, 1], x[t, 2], x[t, 3] = z[c, 0], z[c, 1], 0.0, 0.0
        P[t] = 0.0
        P[t, 0, 0] = P[t, 1, 1] = mv
        P[t, 2, 2] = P[t, 3, 3] = speed_var
        exist[t] = birth_exist
        lo_score[t] = lo_shape[t] = lo_motion[t] = 0.0
        lo_resid[t] = res_chi2[t] = res_dof[t] = 0.0
        score_sum[t] = n_scored[t] = 0.0
        seen[t] = 1
        age[t] = 0
        static_t[t] = 0.0
        moved[t] = False
        confirmed[t] = birth_exist >= confirm_exist
        npts[t] = head[t] = 0
        # the housing's centre is r behind the visible arc's middle, seen from the observer
        ax, ay = z[c, 0] - poses[o, 0], z[c, 1] - poses[o, 1]
        an = max(math.sqrt(ax * ax + ay * ay), 1e-9)
        fit_c[t, 0] = z[c, 0] + ax / an * r * 0.5
        fit_c[t, 1] = z[c, 1] + ay / an * r * 0.5
        anchor[t, 0], anchor[t, 1] = z[c, 0], z[c, 1]
        anchor_var[t] = mv
        anchor_odo[t] = odometer[o]
        anchor_rng[t] = rng[c]
    return ti, ci, tb, born, next_id


@numba.njit(cache=True, nogil=True)
def _finish_kernel_before(pre, hit, dt, alive, tobs, x, P, poses, exist, confirmed, moved, lo_motion,
                          static_t, age, seen, anchor, anchor_var, anchor_odo, anchor_rng, odometer, p_detect,
                          clutter, max_range, confirm_exist, delete_exist, motion_dist, motion_gain,
                          head_rate2, pos_rate2):  # fmt: skip
    """Existence (Bayes: hit, or a miss when in range), confirm; the motion cue; age; delete."""
    for t in range(alive.shape[0]):
        if pre[t]:
            p = exist[t]
            if hit[t]:
                exist[t] = p / (p + (1 - p) * clutter)
            else:
                o = tobs[t]
                if math.hypot(x[t, 0] - poses[o, 0], x[t, 1] - poses[o, 1]) <= max_range:
                    exist[t] = p * (1 - p_detect) / (1 - p * p_detect)
    for t in range(alive.shape[0]):
        if not alive[t]:
            continue
        if exist[t] >= confirm_exist:
            confirmed[t] = True
        # motion: displaced from where first seen beyond 3 sigma, sigma including the odometry drift since
        disp = math.hypot(x[t, 0] - anchor[t, 0], x[t, 1] - anchor[t, 1])
        aged = odometer[tobs[t]] - anchor_odo[t]
        drift = aged * (head_rate2 * anchor_rng[t] ** 2 + pos_rate2)
        var = anchor_var[t] + 0.5 * (P[t, 0, 0] + P[t, 1, 1]) + drift
        if disp > motion_dist and disp > 3.0 * math.sqrt(var) and seen[t] > 2:
            moved[t] = True
        lo_motion[t] = motion_gain if moved[t] else 0.0
        static_t[t] += dt
        age[t] += 1
        alive[t] = exist[t] >= delete_exist
