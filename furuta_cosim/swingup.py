"""Swing-up and catch: an energy-based swing-up that hands the pendulum to a balance controller.

A real pendulum starts hanging down. The swing-up pumps energy into it (Astrom and Furuta,
"Swinging up a pendulum by energy control", Automatica 36, 2000): with the pendulum's energy

    E = 1/2 J dtheta1^2 + m g l (cos theta1 - 1)      (0 upright at rest, -2 m g l hanging)

normalized as e = E / (2 m g l) (-1 hanging at rest, 0 upright at rest), the voltage

    V = sat( k_e (e_ref - e) dtheta1 cos theta1 - k_a theta0 - d_a dtheta0 ,  V_s )

adds energy while e < e_ref and keeps the arm near its zero (a QUBE's arm meets end stops at
about +-2.4 rad). Once the pendulum, its angle wrapped to (-pi, pi], is within ``catch_angle``
of upright (and turns slower than ``catch_rate``), the balance controller takes over, its state
reset; if it falls beyond ``fall_angle`` the swing-up takes over again. The balance controller
sees the wrapped angle, so an upright reached the other way round (theta1 = 2 pi) is upright.

A controller file of this kind::

    name: swingup-qube
    type: swingup
    balance: lqr-qube.yaml          # any controller file, beside this one or a name
    plant: qube-servo-3             # the pendulum's m_p, l_p, I_p and g (the energy)
    swingup: {energy_gain: 20.0, voltage: 5.0, arm_gain: 1.0, arm_damping: 0.2,
              catch_angle: 0.3, fall_angle: 0.8, catch_rate: 12.0, energy: 0.0, direction: 1}

:class:`DampDown` is the reverse law, used between runs: it takes the energy out (``e_ref`` = -1,
hanging at rest) and brings the arm home.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

# every setting, its default and its bounds: the one place they are stated
SETTINGS = {
    "energy_gain": (20.0, 0.0, 1e4, "V s/rad per unit of normalized energy short of the target"),
    "voltage": (5.0, 0.0, 1e3, "the swing-up's own voltage limit (V)"),
    "arm_gain": (1.0, 0.0, 1e4, "V per rad pulling the arm to its zero while swinging up"),
    "arm_damping": (0.2, 0.0, 1e4, "V s/rad damping the arm while swinging up"),
    "catch_angle": (0.3, 1e-3, math.pi, "rad from upright where the balance controller takes over"),
    "fall_angle": (0.8, 1e-3, math.pi, "rad from upright where the swing-up takes over again"),
    "catch_rate": (12.0, 1e-3, 1e4, "rad/s: the pendulum is caught only when it turns slower"),
    "energy": (0.0, -1.0, 1.0, "normalized energy the swing-up aims at (0: upright at rest)"),
    "direction": (1.0, -1.0, 1.0, "+1 or -1: the sense in which voltage adds energy on this rig"),
}


@dataclass(frozen=True)
class SwingUp:
    """The settings of the energy swing-up and the catch, and the pendulum they act on:
    ``inertia`` about its pivot (kg m^2), ``mgl`` = m_p g l_p (N m)."""

    inertia: float
    mgl: float
    energy_gain: float = SETTINGS["energy_gain"][0]
    voltage: float = SETTINGS["voltage"][0]
    arm_gain: float = SETTINGS["arm_gain"][0]
    arm_damping: float = SETTINGS["arm_damping"][0]
    catch_angle: float = SETTINGS["catch_angle"][0]
    fall_angle: float = SETTINGS["fall_angle"][0]
    catch_rate: float = SETTINGS["catch_rate"][0]
    energy: float = SETTINGS["energy"][0]
    direction: float = SETTINGS["direction"][0]

    def settings(self) -> dict[str, float]:
        """The tunable settings (everything but the pendulum's own values)."""
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name in SETTINGS}

    def with_settings(self, **changes: float) -> "SwingUp":
        return replace(self, **changes)


def pendulum(parameters) -> tuple[float, float]:
    """(inertia about the pivot, m g l) of the pendulum of a Furuta plant's parameters (I_p is
    about the pendulum's centre of mass, as the model declares it)."""
    m, l, inertia, g = (float(parameters[k]) for k in ("m_p", "l_p", "I_p", "g"))
    return inertia + m * l * l, m * g * l


def wrap(angle: float) -> float:
    """The angle in (-pi, pi]."""
    wrapped = math.fmod(angle + math.pi, 2.0 * math.pi)
    if wrapped <= 0.0:
        wrapped += 2.0 * math.pi
    return wrapped - math.pi


def normalized_energy(s: SwingUp, theta1: float, dtheta1: float) -> float:
    """The pendulum's energy over 2 m g l: -1 hanging at rest, 0 upright at rest."""
    return (0.5 * s.inertia * dtheta1 * dtheta1 + s.mgl * (math.cos(theta1) - 1.0)) / (2.0 * s.mgl)


def energy_voltage(s: SwingUp, x, target: float, gain: float, limit: float) -> float:
    """The energy law's voltage toward the normalized energy ``target``, arm kept home."""
    theta0, dtheta0, theta1, dtheta1 = x[0], x[1], x[2], x[3]
    e = normalized_energy(s, theta1, dtheta1)
    # the pendulum's phase: its rate times cos theta1 (Astrom and Furuta's smooth form; the
    # sign of it alone makes the voltage chatter, the arm's push reversing dtheta1 each sample)
    phase = dtheta1 * math.cos(theta1)
    if abs(phase) < KICK_RATE and target > e + 0.5:
        phase = KICK_RATE  # a pendulum hanging still gets its first push
    v = s.direction * gain * (target - e) * phase - s.arm_gain * theta0 - s.arm_damping * dtheta0
    return max(-limit, min(limit, v))


KICK_RATE = 0.05  # rad/s: below it a pendulum far short of its target energy is pushed


SWINGUP, BALANCE = 0.0, 1.0  # the mode, recorded as the controller's last state


class SwingUpRuntime:
    """The swing-up and catch around a runtime balance controller (the same calls as
    :class:`~furuta_cosim.cosim.runtime.RuntimeController`: ``control(x, rbar)``, ``reset()``,
    ``state()``): states are the balance controller's, then the mode (0 swinging up, 1
    balancing). Runs on the plant's states (simulation) or on estimated ones (a rig). With
    ``delay=1`` every command is applied a sample late (the balance controller is then built
    without a delay of its own)."""

    native = False  # the sample loop in C runs linear controllers only

    def __init__(self, balance, settings: SwingUp, delay: int = 0):
        self.balance, self.settings, self.delay = balance, settings, delay
        self.n_xc = balance.n_xc + 1
        self.reset()

    def __reduce__(self):
        return (SwingUpRuntime, (self.balance, self.settings, self.delay))

    def reset(self) -> None:
        self.balance.reset()
        self.mode = SWINGUP
        self.switches: list[tuple[int, float]] = []  # (sample, new mode)
        # following a logged mode (:meth:`follow`): (sample, the mode its own rule gave) at each
        # sample where the rule and the logged mode disagree
        self.own: list[tuple[int, float]] = []
        self._forced: float | None = None
        self._k = 0
        self._held = 0.0  # with delay 1: the command of the sample before

    def follow(self, mode: float) -> None:
        """Run the next sample in ``mode`` whatever its own rule says (a replay following the
        mode a log recorded); where the rule would have made another mode, :attr:`own` keeps
        it."""
        self._forced = float(mode)

    def state(self) -> list[float]:
        return self.balance.state() + [self.mode]

    def control(self, x, rbar: float) -> float:
        if not self.delay:
            return self._control(x, rbar)
        u, self._held = self._held, self._control(x, rbar)  # computed now, applied next sample
        return u

    def _control(self, x, rbar: float) -> float:
        s = self.settings
        theta1 = wrap(x[2])
        rule = self.mode
        if self.mode == SWINGUP and abs(theta1) < s.catch_angle and abs(x[3]) < s.catch_rate:
            rule = BALANCE
        elif self.mode == BALANCE and abs(theta1) > s.fall_angle:
            rule = SWINGUP
        new = rule
        if self._forced is not None:
            new, self._forced = self._forced, None
            if rule != new:
                self.own.append((self._k, rule))
        if new != self.mode:
            if new == BALANCE:
                self.balance.reset()
            self.mode = new
            self.switches.append((self._k, new))
        self._k += 1
        if self.mode == BALANCE:
            return self.balance.control([x[0], x[1], theta1] + list(x[3:]), rbar)
        return energy_voltage(s, x, s.energy, s.energy_gain, s.voltage)

    __call__ = control


class DampDown:
    """Brings the rig to rest between runs: the energy law reversed (toward hanging at rest)
    with gentle gains of its own (a random search over starts 1 and 2.5 rad off hanging on the
    qube-servo-3 plant: at rest within 3.8 s, at most 2 V), and the arm pulled home; ``done(x)``
    once the pendulum hangs still and the arm is home. Within ``release`` rad of upright it
    applies 0 V and lets the pendulum fall: braking a pendulum that falls from upright threw
    the arm to its 2 rad limit within 0.8 s, where released it comes to rest within 4.2 s with
    the arm within 0.72 rad (virtual board, starts 0.02 to 0.1 rad from upright)."""

    def __init__(self, inertia: float, mgl: float, gain: float = 2.0, voltage: float = 2.0,
                 arm_gain: float = 1.4, arm_damping: float = 0.15, arm_tolerance: float = 0.05,
                 energy_tolerance: float = 0.002, rate_tolerance: float = 0.05, release: float = 2.5):
        self.settings = SwingUp(inertia, mgl, energy_gain=gain, voltage=voltage, arm_gain=arm_gain,
                                arm_damping=arm_damping)
        self.release = release
        self.tolerances = (arm_tolerance, energy_tolerance, rate_tolerance)

    def control(self, x) -> float:
        if abs(wrap(x[2])) < self.release:
            return 0.0
        s = self.settings
        return energy_voltage(s, x, -1.0, s.energy_gain, s.voltage)

    def done(self, x) -> bool:
        arm, energy, rate = self.tolerances
        e = normalized_energy(self.settings, x[2], x[3])
        return abs(x[0]) < arm and abs(x[1]) < rate and abs(e + 1.0) < energy and abs(x[3]) < 10 * rate
