"""Cascaded flight controller of the simulated GLMAV (flies on the true state).

position -> velocity -> thrust vector / attitude -> body rates -> actuators:

1. Velocity command from the setpoint: ``v_cmd = k_pos (p_sp - p)`` (limited), or a
   velocity / turning-climb setpoint.
2. Acceleration command ``a_cmd = k_v (v_cmd - v) + k_i int(v_cmd - v) + a_ff``; the
   thrust vector cancels the modelled body aerodynamics (eqs (6)-(8), no wind):
   ``T = m a_cmd - m g e3 - F_aero`` (NED), tilt limited.
3. Attitude from the thrust direction (body -z along T) and the yaw setpoint; the
   quaternion error gives rate commands; rate errors give angular accelerations and
   moments ``tau = I alpha + omega x I omega``.
4. Actuators: collective and yaw solve the 2x2 system of eqs (5) and (10)
   ``sigma alpha W1^2 + sigma beta c W2^2 = T_axial``, ``gamma1 W1^2 + gamma2 W2^2 = N``;
   the cyclic inverts eq. (10): ``sin dcx = -L / (d beta W2^2)``,
   ``sin dcy = M / (d beta W2^2 cos dcx)``, clipped to the swash-plate limit.

The controller sees the truth: scenarios then fly the same whatever sensor faults
are injected (faults only change what the vehicle reports).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from glmav_sitl.dynamics.frames import quat_conj, quat_from_euler, quat_mul, rotation_from_quat
from glmav_sitl.params import VehicleParams
from glmav_sitl.scenario import ControllerGains, Setpoint


def _clip(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else (hi if x > hi else x)


@dataclass
class _Active:
    sp: Setpoint
    t0_s: float
    p0_ned: tuple[float, float, float]
    yaw0_rad: float


class Controller:
    """``update(t_s, x) -> u`` at the control rate; ``u`` as in :mod:`glmav_sitl.dynamics.model`."""

    def __init__(
        self,
        p: VehicleParams,
        gains: ControllerGains,
        setpoints: Sequence[Setpoint],
        control_dt_s: float,
    ) -> None:
        self.p = p
        self.k = gains
        self.setpoints = sorted(setpoints, key=lambda s: s.t_s)
        self.dt = control_dt_s
        self._idx = -1
        self._active: _Active | None = None
        self._vi = [0.0, 0.0, 0.0]
        self._kx = 0.5 * p.rho * p.side_area_m2 * p.cx
        self._ky = 0.5 * p.rho * p.side_area_m2 * p.cy
        self._kz = 0.5 * p.rho * p.top_area_m2 * p.cz
        self._dw = p.downwash_hover / math.sqrt(p.m * p.g)
        self.last_attitude_sp_rad = (0.0, 0.0, 0.0)

    def _select(self, t_s: float, p_ned: tuple[float, float, float], yaw: float) -> _Active | None:
        i = self._idx
        while i + 1 < len(self.setpoints) and self.setpoints[i + 1].t_s <= t_s:
            i += 1
        if i != self._idx:
            self._idx = i
            self._active = _Active(self.setpoints[i], t_s, p_ned, yaw)
        return self._active

    def command(self, sp: Setpoint, t_s: float, x: Sequence[float]) -> None:
        """Fly ``sp`` from now on, in place of the scheduled setpoints (a ground station's
        command). ``hold`` and ``position`` without a position hold where ``x`` is now."""
        self._idx = len(self.setpoints)  # the schedule is over: no scheduled setpoint replaces it
        r = rotation_from_quat(x[6], x[7], x[8], x[9])
        yaw = math.atan2(float(r[1, 0]), float(r[0, 0]))
        self._active = _Active(sp, t_s, (x[0], x[1], x[2]), yaw)
        if sp.kind == "idle":
            self._vi = [0.0, 0.0, 0.0]

    def update(self, t_s: float, x: Sequence[float]) -> list[float]:
        p, k = self.p, self.k
        qw, qx, qy, qz = x[6], x[7], x[8], x[9]
        (r11, r12, r13), (r21, r22, r23), (r31, r32, r33) = rotation_from_quat(
            qw, qx, qy, qz
        ).tolist()
        yaw = math.atan2(r21, r11)
        pos = (x[0], x[1], x[2])
        vu, vv, vw = x[3], x[4], x[5]
        v_ned = (
            r11 * vu + r12 * vv + r13 * vw,
            r21 * vu + r22 * vv + r23 * vw,
            r31 * vu + r32 * vv + r33 * vw,
        )
        act = self._select(t_s, pos, yaw)
        if act is None or act.sp.kind == "idle":
            self._vi = [0.0, 0.0, 0.0]
            return [0.0, 0.0, 0.0, 0.0]
        sp = act.sp
        a_ff = [0.0, 0.0, 0.0]
        yaw_sp = sp.yaw_rad if sp.yaw_rad is not None else act.yaw0_rad
        if sp.kind in ("position", "hold"):
            target = sp.position_ned_m if sp.position_ned_m is not None else act.p0_ned
            v_cmd = [k.pos_p * (target[i] - pos[i]) for i in range(3)]
        elif sp.kind == "velocity":
            v_cmd = list(sp.velocity_ned_mps)
        else:  # turn: heading sweeps at turn_rate, speed along heading, climb rate up
            psi = act.yaw0_rad + sp.turn_rate_radps * (t_s - act.t0_s)
            yaw_sp = psi
            v_cmd = [sp.speed_mps * math.cos(psi), sp.speed_mps * math.sin(psi), -sp.climb_rate_mps]
            # centripetal feed-forward: d/dt of the commanded velocity
            a_ff = [
                -sp.speed_mps * sp.turn_rate_radps * math.sin(psi),
                sp.speed_mps * sp.turn_rate_radps * math.cos(psi),
                0.0,
            ]
        vh = math.hypot(v_cmd[0], v_cmd[1])
        if vh > k.max_speed_mps:
            v_cmd[0] *= k.max_speed_mps / vh
            v_cmd[1] *= k.max_speed_mps / vh
        v_cmd[2] = _clip(v_cmd[2], -k.max_speed_mps, k.max_speed_mps)
        # velocity loop (PI) -> acceleration command, NED
        a_cmd = [0.0, 0.0, 0.0]
        for i in range(3):
            e = v_cmd[i] - v_ned[i]
            # conditional integration (anti-windup): only near the commanded velocity
            if abs(e) < 1.0:
                self._vi[i] = _clip(
                    self._vi[i] + e * self.dt,
                    -k.max_accel_mps2 / k.vel_i,
                    k.max_accel_mps2 / k.vel_i,
                )
            a_cmd[i] = k.vel_p * e + k.vel_i * self._vi[i] + a_ff[i]
        ah = math.hypot(a_cmd[0], a_cmd[1])
        if ah > k.max_accel_mps2:
            a_cmd[0] *= k.max_accel_mps2 / ah
            a_cmd[1] *= k.max_accel_mps2 / ah
        a_cmd[2] = _clip(a_cmd[2], -k.max_accel_mps2, k.max_accel_mps2)
        # modelled body aerodynamics, eqs (6)-(8) with no wind, body -> NED
        w1, w2, dcx, dcy = x[13], x[14], x[15], x[16]
        t_ax = p.sigma * (p.alpha * w1 * w1 + p.beta * w2 * w2 * math.cos(dcx) * math.cos(dcy))
        vp = self._dw * math.sqrt(t_ax) if t_ax > 0.0 else 0.0
        ax_, ay_, az_ = -vu, -vv, vp - vw
        nrm = math.sqrt(ax_ * ax_ + ay_ * ay_ + az_ * az_)
        fb = (self._kx * ax_ * nrm, self._ky * ay_ * nrm, self._kz * az_ * nrm)
        fa = (
            r11 * fb[0] + r12 * fb[1] + r13 * fb[2],
            r21 * fb[0] + r22 * fb[1] + r23 * fb[2],
            r31 * fb[0] + r32 * fb[1] + r33 * fb[2],
        )
        # thrust vector (NED): T = m a - m g e3 - F_aero
        tn = p.m * a_cmd[0] - fa[0]
        te = p.m * a_cmd[1] - fa[1]
        td = p.m * (a_cmd[2] - p.g) - fa[2]
        td = min(td, -0.2 * p.m * p.g)  # always some upward thrust
        th = math.hypot(tn, te)
        tmax = -td * math.tan(k.max_tilt_rad)
        if th > tmax:
            tn *= tmax / th
            te *= tmax / th
        tnorm = math.sqrt(tn * tn + te * te + td * td)
        cpsi, spsi = math.cos(yaw_sp), math.sin(yaw_sp)
        tf = cpsi * tn + spsi * te
        tr = -spsi * tn + cpsi * te
        phi_sp = math.asin(_clip(tr / tnorm, -1.0, 1.0))
        theta_sp = math.atan2(-tf, -td)
        self.last_attitude_sp_rad = (phi_sp, theta_sp, yaw_sp)
        q = (qw, qx, qy, qz)
        qe = quat_mul(quat_conj(q), quat_from_euler(phi_sp, theta_sp, yaw_sp))
        if qe[0] < 0.0:
            qe = (-qe[0], -qe[1], -qe[2], -qe[3])
        wr = k.max_rate_radps
        w_cmd = (
            _clip(2.0 * k.att_p * qe[1], -wr, wr),
            _clip(2.0 * k.att_p * qe[2], -wr, wr),
            _clip(2.0 * k.yaw_p * qe[3], -wr, wr),
        )
        wp, wq, wr_ = x[10], x[11], x[12]
        al = (
            k.rate_p * (w_cmd[0] - wp),
            k.rate_p * (w_cmd[1] - wq),
            k.yaw_rate_p * (w_cmd[2] - wr_),
        )
        # eq. (4): tau = I alpha + omega x I omega
        L = p.ixx * al[0] + (wq * p.izz * wr_ - wr_ * p.iyy * wq)
        M = p.iyy * al[1] + (wr_ * p.ixx * wp - wp * p.izz * wr_)
        N = p.izz * al[2] + (wp * p.iyy * wq - wq * p.ixx * wp)
        # collective along the actual -z_b
        t_axial = max(0.0, -(tn * r13 + te * r23 + td * r33))
        # eqs (5), (10): solve for W1^2, W2^2
        c = math.cos(dcx) * math.cos(dcy)
        sa, sbc = p.sigma * p.alpha, p.sigma * p.beta * c
        det = sa * p.gamma2 - sbc * p.gamma1
        w1s = (t_axial * p.gamma2 - sbc * N) / det
        w2s = (sa * N - p.gamma1 * t_axial) / det
        w1c = math.sqrt(max(w1s, 0.0))
        w2c = math.sqrt(max(w2s, 0.0))
        # cyclic: invert eq. (10) with the actual lower rotor speed
        b2 = max(p.beta * w2 * w2, 0.05 * p.m * p.g)
        smax = math.sin(p.swash_limit)
        sx = _clip(-L / (p.d * b2), -smax, smax)
        dcx_c = math.asin(sx)
        sy = _clip(M / (p.d * b2 * math.cos(dcx_c)), -smax, smax)
        return [w1c, w2c, dcx_c, math.asin(sy)]
