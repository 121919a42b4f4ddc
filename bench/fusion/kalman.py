"""Constant-acceleration Kalman filter over the odometer speed (SPEED_REF, 50 Hz).

The model is the usual constant-acceleration one: state (position, speed, acceleration),
white jerk of spectral density ``q`` as process noise (continuous-time CA model), the
odometer speed with noise ``r`` (m/s) as the measurement. Position is never measured, and
in this model it never feeds back: its row of the covariance does not enter the speed and
acceleration gains, so dropping it changes neither estimate by a single bit of arithmetic
that matters here. The filter therefore runs on (speed, acceleration).

Scalar Python floats on purpose: a scalar recursion gives the same float64 values however
the frames were batched, where vectorised reductions would round differently. For speed
(replay feeds ~50 k frames/s through here) the covariance update is skipped once it has
reached its floating-point fixed point for the current step length: the covariance does
not depend on the measurements, so from a fixed point every later step with the same dt
computes the very same numbers again.
"""

from __future__ import annotations

ACCEL0_MPS2 = 1.0
"""Initial acceleration uncertainty (1 sigma): about the largest a train pulls or brakes at."""
MANEUVER_SIGMA = 4.0
MANEUVER_FRAMES = 2
"""That many speed innovations in a row beyond MANEUVER_SIGMA standard deviations, all of one
sign, mean the acceleration has changed: its uncertainty is reset to ACCEL0_MPS2."""


class SpeedKalman:
    """The filter state; :meth:`run` feeds it measurements in order."""

    def __init__(self, speed_noise_mps: float, jerk_psd: float) -> None:
        self.r2 = speed_noise_mps * speed_noise_mps
        self.q = jerk_psd
        self.speed = 0.0
        self.acc = 0.0
        self.cov = (self.r2, 0.0, ACCEL0_MPS2 * ACCEL0_MPS2)  # P: vv, va, aa
        self._fixed_dt: float | None = None  # dt for which cov is a fixed point...
        self._gain = (0.0, 0.0, 1.0)  # ...and the gain (kv, ka) and innovation variance
        self._streak = (0, False)  # innovations outside the gate in a row, and their sign

    def run(
        self, dt: list[float], z: list[float], restart: list[bool]
    ) -> tuple[list[float], list[float]]:
        """Per measurement z (m/s): restart at z (acceleration unknown), or predict over dt s
        and update. Returns the acceleration estimate and its variance after each one."""
        q, r2 = self.q, self.r2
        a0 = ACCEL0_MPS2 * ACCEL0_MPS2
        gate = MANEUVER_SIGMA * MANEUVER_SIGMA

        def predict(vv: float, va: float, aa: float, h: float) -> tuple[float, float, float]:
            # P' = F P F^T + Q, F = [[1, dt], [0, 1]], Q from white jerk of density q
            s2 = va + h * aa
            return vv + h * va + h * s2 + q * h * h * h / 3.0, s2 + q * h * h / 2.0, aa + q * h

        speed, acc = self.speed, self.acc
        vv, va, aa = self.cov
        fixed = self._fixed_dt
        kv, ka, s = self._gain
        streak, up = self._streak
        acc_out: list[float] = []
        var_out: list[float] = []
        add_acc, add_var = acc_out.append, var_out.append
        gate_s = gate * s
        for h, zk, rk in zip(dt, z, restart, strict=True):
            if rk:
                speed, acc = zk, 0.0
                vv, va, aa = r2, 0.0, a0
                fixed = None
                streak = 0
                add_acc(acc)
                add_var(aa)
                continue
            speed = speed + h * acc
            innov = zk - speed
            if fixed == h and not innov * innov > gate_s:
                streak = 0  # the usual step: covariance at its fixed point, innovation in gate
            else:
                refresh = fixed != h
                if refresh:
                    pvv, pva, paa = predict(vv, va, aa, h)
                    s = pvv + r2
                    gate_s = gate * s
                # manoeuvre: the acceleration changed (a step is an infinite jerk the model
                # calls impossible): start its estimate afresh instead of lagging for seconds
                if innov * innov > gate_s:
                    streak = streak + 1 if (innov > 0.0) == up or streak == 0 else 1
                    up = innov > 0.0
                else:
                    streak = 0
                if streak >= MANEUVER_FRAMES:
                    streak = 0
                    pvv, pva, paa = predict(r2, 0.0, a0, h)
                    s = pvv + r2
                    gate_s = gate * s
                    refresh, fixed = True, None
                if refresh:
                    kv, ka = pvv / s, pva / s
                    new = (pvv - kv * pvv, pva - kv * pva, paa - ka * pva)  # P -= K H P
                    if new == (vv, va, aa):
                        fixed = h
                    vv, va, aa = new
            speed = speed + kv * innov
            acc = acc + ka * innov
            add_acc(acc)
            add_var(aa)
        self.speed, self.acc = speed, acc
        self.cov = (vv, va, aa)
        self._fixed_dt = fixed
        self._gain = (kv, ka, s)
        self._streak = (streak, up)
        return acc_out, var_out
