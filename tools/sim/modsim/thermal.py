"""First-order thermal process and the controllers' own control law.

The process: tau * dT/dt = ambient + gain * u - T for a heating output u in 0..1 (cooling,
direct action: - gain * u). The controller of each model drives u from PV and SV with its own
parameters, so a PLC example that writes SV sees real dynamics (speed set by --time-scale).
"""
from __future__ import annotations


class Plant:
    """First-order lag. Defaults: 25.0 ambient, 500 degrees full-output rise, 120 s lag."""

    def __init__(self, ambient: float = 25.0, gain: float = 500.0, tau: float = 120.0):
        self.ambient, self.gain, self.tau = ambient, gain, tau
        self.temp = ambient
        self.hold = False            # control 'plant' op: freeze PV (e.g. to test alarms)

    def step(self, u: float, dt: float, cooling: bool = False):
        """Advance dt seconds with output u (0..1); sub-steps keep Euler stable."""
        if self.hold or dt <= 0:
            return
        drive = self.ambient + (-1 if cooling else 1) * self.gain * max(0.0, min(1.0, u))
        steps = max(1, int(dt / (self.tau / 20.0)) + 1)
        h = dt / steps
        for _ in range(steps):
            self.temp += (drive - self.temp) * h / self.tau

    def configure(self, **kw) -> dict:
        for key in ("ambient", "gain", "tau", "temp"):
            if key in kw:
                setattr(self, key, float(kw[key]))
        if "hold" in kw:
            self.hold = bool(kw["hold"])
        return {"ambient": self.ambient, "gain": self.gain, "tau": self.tau,
                "temp": self.temp, "hold": self.hold}


class Pid:
    """Positional PID with anti-windup, output in percent 0..100.

    band: proportional band in engineering units (0 = on/off with hysteresis `hyst`).
    ti, td: seconds (ti = 0: no integral); bias: manual-reset term in percent.
    """

    def __init__(self):
        self.integral, self.last_meas, self.on, self.dterm = 0.0, None, False, 0.0

    def reset(self):
        self.integral, self.last_meas, self.on, self.dterm = 0.0, None, False, 0.0

    def step(self, err: float, meas: float, dt: float, band: float, ti: float, td: float,
             bias: float = 0.0, hyst: float = 0.0) -> float:
        """Output percent for error err (SV - PV when heating, PV - SV when cooling).

        meas is the measurement in the same sense (PV heating, -PV cooling): derivative on
        measurement, so an SV step gives no derivative kick.
        """
        if band <= 0:
            if err > hyst / 2:
                self.on = True
            elif err < -hyst / 2:
                self.on = False
            return 100.0 if self.on else 0.0
        p = 100.0 * err / band
        d = 0.0
        if td > 0 and self.last_meas is not None and dt > 0:
            raw_d = -100.0 / band * td * (meas - self.last_meas) / dt
            # derivative filtered with time constant td / 8, as industrial PIDs do
            self.dterm += (raw_d - self.dterm) * dt / (dt + td / 8.0)
            d = self.dterm
        self.last_meas = meas
        if ti > 0 and dt > 0:
            trial = self.integral + 100.0 * err / band * dt / ti
            unsat = p + trial + d + bias
            if 0.0 <= unsat <= 100.0 or (unsat > 100.0 and err < 0) or (unsat < 0.0 and err > 0):
                self.integral = trial          # conditional integration (anti-windup)
        return max(0.0, min(100.0, p + self.integral + d + bias))


SAMPLE_S = 0.25      # the controllers' sampling period (simulated seconds)


class Loop:
    """A controller's loop: its Pid driving one Plant. Models feed it their own parameters."""

    def __init__(self):
        self.plant = Plant()
        self.pid = Pid()
        self.output = 0.0            # percent, as the controller's MV would show it
        self.manual = None           # percent when in manual mode (FDC), else None

    def run(self, dt: float, sv: float, band: float, ti: float, td: float,
            bias: float = 0.0, hyst: float = 0.0, cooling: bool = False):
        """dt simulated seconds: control law then process, sampled every SAMPLE_S at most."""
        steps = max(1, int(dt / SAMPLE_S + 0.999))
        h = dt / steps
        sign = -1.0 if cooling else 1.0
        for _ in range(steps):
            pv = self.plant.temp
            if self.manual is not None:
                self.output = self.manual
            else:
                self.output = self.pid.step(sign * (sv - pv), sign * pv, h, band, ti, td,
                                            bias, hyst)
            self.plant.step(self.output / 100.0, h, cooling)

    def restart(self):
        """Power cycle: the controller's memory is lost, the process keeps its temperature."""
        self.pid.reset()
        self.output = 0.0
        self.manual = None
