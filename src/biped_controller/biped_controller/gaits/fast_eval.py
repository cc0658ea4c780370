"""A cheaper evaluation of the step NLP (the same problem as :class:`StepOptimizer`, other arithmetic).

* **End of step**: for a fixed pre-impact configuration q(T), everything the end-of-step conditions
  use is linear in the pre-impact velocities q'(T): the post-impact velocity (v+ = v- + M^-1 J^T Lambda,
  Lambda = -(J M^-1 J^T)^-1 J v-), the impulse, the former stance foot's velocity, the swing ankle's
  velocity. One evaluation of those linear maps gives their values and their exact derivative in
  q'(T); only the derivative in q(T) is still taken by central differences (6 columns, 12 evaluations,
  instead of 12 columns and 24 evaluations of the whole impact).
* **Grid**: inverse dynamics and its derivatives at the 41 instants with one Pinocchio call each
  (``computeRNEADerivatives`` fills ``data.tau``, and the joint placements and Jacobians the swing foot's
  height and its Jacobian are read from, too), the chain rule through the polynomial basis (one batched
  product with the stacked basis phi, phi', phi''), the criterion and the 17 margin rows batched over the
  grid in NumPy; the matrices that depend on the basis alone are made again only when it changes.

The values agree with :meth:`StepOptimizer.evaluate` to round-off and the gradients to the accuracy
of its finite differences (``tests/test_gait_build.py``); the iterates, hence the family, differ in
the last bits, so this evaluator's family is compared with the reference one within the fit
tolerances, not bit for bit.
"""
from __future__ import annotations


import numpy as np
import pinocchio as pin

from biped_model.description import LEFT
from biped_model.floating import PAPER_FROM_URDF

from biped_controller.gaits.optimizer import NJ, StepOptimizer


class FastStepOptimizer(StepOptimizer):
    """:class:`StepOptimizer` with :meth:`evaluate` computed as described in the module docstring."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        n = self.n
        ft = self.desc.foot
        self._ls = np.array([ft.l_min, ft.l_max])
        self._inner = np.arange(1, n)
        self._U = PAPER_FROM_URDF[LEFT].T          # URDF joint velocities from paper q' (stance LEFT)
        self._P_new = PAPER_FROM_URDF[1 - LEFT]    # paper q' of the new stance from URDF joint velocities
        self._R = -np.eye(6)[::-1]
        self._knee_jac = None
        self._basis_key = None
        self._upper = np.triu(np.ones((9, 9), dtype=bool))

    # ------------------------------------------------------------ end of step
    def _end_maps(self, Q: np.ndarray) -> np.ndarray:
        """(B, 11, 6) matrices A(q(T)) for the B configurations ``Q`` (B, 6): rows [q'(0+) (6), swing ankle
        v_x, v_z, impulse Lambda_x, Lambda_z, vertical velocity of the former stance foot] = A q'(T).
        Pinocchio per configuration, the linear algebra batched."""
        fl = self.floating
        model, data = fl.model, fl.data
        Q = np.atleast_2d(Q)
        B = Q.shape[0]
        st_id, new_id = fl.foot_ids[LEFT], fl.foot_ids[1 - LEFT]
        lwa = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
        Jst = np.empty((B, 3, 9))
        Jn = np.empty((B, 3, 9))
        M = np.empty((B, 9, 9))
        for b in range(B):
            # the floating state of FloatingModel.state_from_paper (stance foot flat at the origin), one
            # kinematics pass for both feet's Jacobians
            x = np.zeros(9)
            x[3:] = self._U @ Q[b]
            # 0.0 - (x3 + x4) - x5 is np.sum(x[3:6])'s order of additions (three terms: left to right), the same
            # bits without the reduction's call overhead (13 configurations per evaluation)
            x[2] = 0.0 - float(x[3] + x[4] + x[5])
            pin.forwardKinematics(model, data, x)
            pin.updateFramePlacement(model, data, st_id)
            t = data.oMf[st_id].translation
            x[0] -= t[0]
            x[1] -= t[2]
            pin.computeJointJacobians(model, data, x)      # (getFrameJacobian places the frame itself)
            Jst[b] = pin.getFrameJacobian(model, data, st_id, lwa)[[0, 2, 4]]
            Jn[b] = pin.getFrameJacobian(model, data, new_id, lwa)[[0, 2, 4]]
            M[b] = pin.crba(model, data, x)
        Jst[:, 2] *= -1.0
        Jn[:, 2] *= -1.0
        M = np.where(self._upper[None], M, M.transpose(0, 2, 1))
        # base velocity that keeps the stance foot still: v[:3] = -Jst[:, :3]^-1 Jst[:, 3:] v[3:]
        G = np.zeros((B, 9, 6))
        G[:, 3:] = self._U
        G[:, :3] = np.linalg.solve(Jst[:, :, :3], -Jst[:, :, 3:] @ self._U)
        Minv_JT = np.linalg.solve(M, Jn.transpose(0, 2, 1))        # (B, 9, 3)
        JnG = Jn @ G
        Lam = np.linalg.solve(Jn @ Minv_JT, -JnG)                   # (B, 3, 6)
        Vp = G + Minv_JT @ Lam                                       # (B, 9, 6)
        A = np.empty((B, 11, 6))
        A[:, :6] = self._P_new @ Vp[:, 3:]
        A[:, 6:8] = JnG[:, :2]                                       # new foot (the swing ankle) before impact: x, z
        A[:, 8:10] = Lam[:, :2]
        A[:, 10] = (Jst @ Vp)[:, 1]
        return A

    def _end_terms(self, qT: np.ndarray, qdT: np.ndarray):
        """q'(0+) demanded by the impact, the end-of-step inequalities (as ``StepOptimizer._endpoint``),
        and their Jacobians w.r.t. (q(T), q'(T)) (6 x 12 and 6 x 12)."""
        st = self.st
        eps = 1e-7
        E = eps * np.eye(6)
        As = self._end_maps(np.vstack([qT[None, :], qT + E, qT - E]))   # (13, 11, 6)
        A = As[0]
        val = A @ qdT
        dval_dq = ((As[1:7] @ qdT) - (As[7:13] @ qdT)).T / (2 * eps)      # (11, 6)
        D = np.hstack([dval_dq, A])                         # (11, 12) d val / d(qT, qdT)
        vx, vz, lx, lz, vo = val[6], val[7], val[8], val[9], val[10]
        mu = st.friction_use * self.desc.mu
        ineq = np.array([
            st.touchdown_speed**2 - vx**2 - vz**2,
            -vz - st.touchdown_descent,
            (lz - st.min_impulse_normal) / 10.0,
            (mu * lz - lx) / 10.0,
            (mu * lz + lx) / 10.0,
            vo - st.liftoff_speed,
        ])
        J_end = np.vstack([
            -2.0 * (vx * D[6] + vz * D[7]),
            -D[7],
            D[9] / 10.0,
            (mu * D[9] - D[8]) / 10.0,
            (mu * D[9] + D[8]) / 10.0,
            D[10],
        ])
        return val[:6], D[:6], ineq, J_end

    # ------------------------------------------------------------ the NLP
    def _basis_terms(self) -> None:
        """The matrices that depend on the basis alone, made again only when it changed (the 1 m/s question
        changes T, hence phi' and phi'', between solves): the stacked basis ``_B`` (n+1, 3, 5) and
        d(q(0)), d(q'(0)), d(q(T)), d(q'(T)) / dz, (6, 30) each, and ``_D_end`` = [d q(T); d q'(T)]."""
        key = self.phi.tobytes() + self.dphi.tobytes() + self.ddphi.tobytes()
        if key == self._basis_key:
            return
        self._basis_key = key
        self._B = np.stack([self.phi, self.dphi, self.ddphi], axis=1)
        rows = (self.phi[0], self.dphi[0], self.phi[-1], self.dphi[-1])
        self._dq0, self._dqd0, self._dqT, self._dqdT = (np.kron(np.eye(NJ), row[None, :]) for row in rows)
        self._D_end = np.vstack([self._dqT, self._dqdT])

    def evaluate(self, z: np.ndarray) -> dict[str, np.ndarray]:
        key = z.tobytes()
        if key == self._cache_key:
            return self._cache
        c = z.reshape(NJ, 5)
        st = self.st
        n = self.n
        q = self.phi @ c.T
        qd = self.dphi @ c.T
        qdd = self.ddphi @ c.T
        model, data = self.model, self.data
        tau = np.empty((n + 1, 9))
        Dq = np.empty((n + 1, 9, 6))
        Dv = np.empty((n + 1, 9, 6))
        Mf = np.empty((n + 1, 9, 9))
        tz = np.empty(n + 1)
        Jz = np.empty((n + 1, 6))
        q9 = np.zeros(9); v9 = np.zeros(9); a9 = np.zeros(9)
        fid = self.fixed.swing_frame
        lwa = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
        for k in range(n + 1):
            q9[3:] = q[k]; v9[3:] = qd[k]; a9[3:] = qdd[k]
            dq_, dv_, ma_ = pin.computeRNEADerivatives(model, data, q9, v9, a9)
            tau[k] = data.tau
            Dq[k] = dq_[:, 3:]
            Dv[k] = dv_[:, 3:]
            Mf[k] = ma_
            if 0 < k < n:       # computeRNEADerivatives has filled data.oMi and data.J at q9 (the same bits as
                pin.updateFramePlacement(model, data, fid)   # computeJointJacobians would; the fast-vs-reference tests cover it)
                tz[k] = data.oMf[fid].translation[2]
                Jz[k] = pin.getFrameJacobian(model, data, fid, lwa)[2, 3:]
        Ma = np.where(self._upper[None], Mf, Mf.transpose(0, 2, 1))[:, :, 3:]   # CRBA part: upper triangle
        self._basis_terms()
        # d tau_k / dz: (n+1, 9, 30), [k, i, 5 j + m] = Dq[k,i,j] phi[k,m] + Dv[k,i,j] phi'[k,m] + Ma[k,i,j] phi''[k,m]
        # (one batched product with the stacked basis, self._B)
        dtau = (np.stack([Dq, Dv, Ma], axis=-1).reshape(n + 1, 54, 3) @ self._B).reshape(n + 1, 9, 30)
        gam = tau[:, 3:]
        wk = self.w
        obj = float(np.sum(wk * np.einsum("ki,ki->k", gam, gam)))
        gobj = 2.0 * ((wk[:, None] * gam).ravel() @ dtau[:, 3:, :].reshape(-1, 30))
        g_rows = tau @ self.C.T + self.d                                  # (n+1, 17)
        g_jac = np.matmul(self.C, dtau).reshape(-1, 30)                   # rows k*17 + r
        # clearance of heel and toe at the inner instants
        inner = self._inner
        ang = np.sum(q[inner], axis=1)
        h = st.clearance * (4.0 * self.s[inner] * (1.0 - self.s[inner])) ** 2
        clear_rows = ((tz[inner, None] + self._ls[None, :] * np.sin(ang)[:, None] - h[:, None]) / 0.01).ravel()
        row = Jz[inner, None, :] + (self._ls[None, :, None] * np.cos(ang)[:, None, None])    # (n-1, 2, 6)
        clear_jac = (row[:, :, :, None] * self.phi[inner][:, None, None, :]).reshape(2 * (n - 1), 30) / 0.01
        obj, gobj, crit = self._objective_terms(obj, gobj, z)
        knee_rows = self._knee_rows(q)
        if self._knee_jac is None:
            self._knee_jac = self._knee_jacobian(n)
        qT, qdT = q[-1], qd[-1]
        qd0_req, J_req, end_ineq, J_end = self._end_terms(qT, qdT)
        D_end = self._D_end                               # (12, 30)
        pose, _ = self.fixed.swing_foot(qT)
        Jsw = self.fixed.swing_foot_jacobian(qT)
        R = self._R
        eq = np.concatenate([pose - np.array([self.p, 0.0, 0.0]), q[0] - R @ qT, (qd[0] - qd0_req) * st.T])
        eq_jac = np.vstack([Jsw @ self._dqT, self._dq0 - R @ self._dqT, (self._dqd0 - J_req @ D_end) * st.T])
        ineq = np.concatenate([g_rows.ravel(), clear_rows, knee_rows, end_ineq])
        ineq_jac = np.vstack([g_jac, clear_jac, self._knee_jac, J_end @ D_end])
        self._cache_key = key
        self._cache = dict(obj=obj, crit=crit, gobj=gobj, eq=eq, eq_jac=eq_jac, ineq=ineq, ineq_jac=ineq_jac)
        return self._cache


def compare_evaluations(ref: StepOptimizer, fast: FastStepOptimizer, z: np.ndarray) -> dict:
    """Largest differences between the two evaluations at z (values and Jacobians), for the tests."""
    a, b = ref.evaluate(np.asarray(z, dtype=float)), fast.evaluate(np.asarray(z, dtype=float))
    return {k: float(np.max(np.abs(np.asarray(a[k]) - np.asarray(b[k])))) if np.size(a[k]) else 0.0 for k in a}


__all__ = ["FastStepOptimizer", "compare_evaluations"]
