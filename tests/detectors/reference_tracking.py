"""The tracker's frame steps and score cue as they were before the compiled kernels (numpy, one array
operation per step): the reference the compiled :class:`detectors.tracking.KinTracker` must reproduce
(same tracks)."""

import numpy as np
from scipy.optimize import linear_sum_assignment

from detectors.tracking import KinTracker


class ReferenceKinTracker(KinTracker):
    """:class:`KinTracker` with the numpy steps (predict, gate, Hungarian, Kalman update, birth,
    existence, motion, confirm / delete)."""

    def _associate_and_birth(self, z, obs, rng, dt):
        rows = np.flatnonzero(self._alive)
        self._predict(rows, dt)
        ti, ci = self._associate(rows, z, obs, rng)
        self._kalman_update(ti, z[ci], rng[ci])
        born = np.setdiff1d(np.arange(z.shape[0]), ci, assume_unique=True)
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
