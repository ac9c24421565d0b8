"""What the encoders' rounding hid: the true angles of a balancing log, estimated.

A controller on a rig sees its angles rounded to whole encoder counts. A replay that closes
its loop with the same rounding is a staircase in the plant's parameters (a fit's finite
differences see steps, not slopes), and one that closes it on exact angles misses the
command's chatter that the rounding drove on the rig, which moves the arm and the current:
measured on a synthetic balancing log, the fitted R_a, M_f and C0 then left their intervals.

So the replay of a balancing log feeds the controller the angles it logged plus the
simulation's departure from the true angles, ``y + (theta_sim - theta_true)``: at the true
parameters it sees exactly what it saw on the rig, and the outputs are smooth in the
parameters. The true angles are estimated in each replay by a Rauch-Tung-Striebel smoother
(a Kalman filter forward, its gains backward) on the plant linearized upright at the values
replayed, driven by the logged voltage (after the loop's delay) and measuring the angles
(noise: the quantum's q^2/12) and the current. On a synthetic log the estimate is within 0.06
quanta RMS of the truth at the true parameters and 0.12 at values 30 % off, against 0.3 for
the counts themselves. Estimated once at the start values instead, the fit needed more than
six rounds of estimating and fitting again to settle, and stayed further from the truth.

Rauch, Tung and Striebel, AIAA Journal 3(8), 1965; closed-loop identification by the direct
method: Forssell and Ljung, Automatica 35(9), 1999.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Mapping

import numpy as np

FRICTION_PASSES = 6       # smoother passes at most with the Coulomb friction added back
FRICTION_SETTLED = 1e-3   # ... until its torque changes by less than this fraction of Tc
# the smoother's process noise: a disturbance on the voltage of this RMS (V); robust to start
# values 30 % off on the synthetic log (0.2 V and 1 V give the same estimate to 0.02 quanta)
INPUT_NOISE = 3.0
# the covariance of the state at a log's first sample, in multiples of the settled one, where
# the log does not say it (a window cut mid-run, or start rates the fit frees: rates no reading
# shows), and when the gains count as settled. A whole log whose start rates are stated starts
# from them with the settled covariance: diffuse there, the synthetic balancing fit's M_f came
# out 5.5 % high, 1.7 % from its stated rest (tests/test_balancing.py)
DIFFUSE = 1e4
SETTLED = 1e-9
# a log whose pendulum leaves this band around upright (rad) is not a balancing log: the
# linear model is not the plant there, and the loop closes on the counted angles instead
UPRIGHT = 0.5


def balancing(experiment) -> bool:
    """Whether a closed-loop log can have its angles estimated: it logs both angles and the
    voltage, and its pendulum stays within UPRIGHT of upright."""
    if experiment.loop is None or "V" not in experiment.inputs:
        return False
    if not {"theta0", "theta1"} <= set(experiment.outputs):
        return False
    pendulum = experiment.outputs["theta1"].values
    return bool(np.all(np.abs(np.mod(pendulum + math.pi, 2 * math.pi) - math.pi) < UPRIGHT))


def _linear(target, values: Mapping[str, float]):
    """(A, B, Bt, C, states, coulomb): the plant linearized upright at ``values`` (Coulomb
    friction left out), continuous: B the voltage's input, Bt the joints' torques' (None where
    the friction is not added back), C the angles' and current's rows; ``coulomb``: None, or
    (each joint's rate's state index, Tc0, Tc1, w_c) to add the friction back as a known
    torque (:func:`estimated_noise`)."""
    from furuta_cosim.fmu.linearize import linearize
    from furuta_cosim.fmu.session import model_description

    parameters = dict(target.fixed)
    parameters.update({k: v for k, v in values.items() if "." not in k})
    declared = {v.name: v for v in model_description(target.fmu).modelVariables}

    def value_of(name: str) -> float:
        if name in parameters:
            return float(parameters[name])
        start = getattr(declared.get(name), "start", None)
        return float(start) if start is not None else 0.0

    coulomb = (value_of("Tc0"), value_of("Tc1"), value_of("w_c"))
    for name in ("Tc0", "Tc1"):   # nonsmooth at rest: no derivative to linearize
        if name in parameters or name in declared:
            parameters[name] = 0.0
    v_name = target.input("V")[0]
    torques = [name for name in ("tau0", "tau1") if name in declared]
    outputs = [target.output(n)[0] for n in ("theta0", "theta1", "i")]
    lin = linearize(target.fmu, parameters=parameters, inputs={v_name: 0.0, **{t: 0.0 for t in torques}},
                    outputs=outputs)
    A, C = np.asarray(lin.A), np.asarray(lin.C)
    B_all = np.asarray(lin.B)
    B = B_all[:, lin.inputs.index(v_name)][:, None]
    rates = [lin.states.index(s) if s in lin.states else None for s in ("dtheta0", "dtheta1")]
    if len(torques) == 2 and None not in rates and (coulomb[0] > 0 or coulomb[1] > 0) and coulomb[2] > 0:
        return A, B, B_all[:, [lin.inputs.index(t) for t in torques]], C, list(lin.states), (rates, *coulomb)
    return A, B, None, C, list(lin.states), None


def _model(target, values: Mapping[str, float], period: float, delay: float):
    """(Ad, B_before, B_now, C, whole, friction, states): the plant linearized upright at ``values``
    (:func:`_linear`) and sampled at ``period``, the voltage reaching the motor ``delay`` after
    its sample: over a sample the motor gets one command for the delay's fraction of a sample
    and the next for the rest. ``friction``: None, or (the discretized input matrix of the
    joints' torques, each joint's rate's state index, Tc0, Tc1, w_c)."""
    from scipy.linalg import expm

    A, B, Bt, C, states, coulomb = _linear(target, values)
    n = A.shape[0]
    friction = None
    if Bt is not None:
        block = np.zeros((n + 2, n + 2))
        block[:n, :n], block[:n, n:] = A * period, Bt * period
        friction = (expm(block)[:n, n:], *coulomb)

    def flow(seconds: float):
        block = np.zeros((n + 1, n + 1))
        block[:n, :n], block[:n, n:] = A * seconds, B * seconds
        M = expm(block)
        return M[:n, :n], M[:n, n:]

    whole = int(math.floor(delay / period + 1e-9))
    part = delay - whole * period
    first, g_first = flow(part) if part > 1e-12 * period else (np.eye(n), np.zeros((n, 1)))
    rest, g_rest = flow(period - part if part > 1e-12 * period else period)
    return rest @ first, (rest @ g_first)[:, 0], g_rest[:, 0], C, whole, friction, states


def _setup(experiment, target, values: Mapping[str, float]):
    """What the smoother of ``experiment`` at ``values`` needs: the model (:func:`_model`),
    the readings ``y`` (the pendulum's turns taken off), their covariance, the voltage at the
    motor over each sample (``before``, ``now``) and the process noise."""
    from scipy.linalg import solve_discrete_are

    if experiment.jittered:
        return _setup_varying(experiment, target, values)
    loop = experiment.loop
    Ad, B_before, B_now, C, whole, friction, states = _model(target, values, experiment.period,
                                                                experiment.loop_delay(values))
    n = Ad.shape[0]
    names = ["theta0", "theta1"] + (["i"] if "i" in experiment.outputs and C.shape[0] > 2 else [])
    C = C[:len(names)]
    y = np.column_stack([experiment.outputs[k].values for k in names])
    turns = 2 * math.pi * round(float(np.mean(y[:, 1])) / (2 * math.pi))  # upright is 0 to the model
    y[:, 1] -= turns
    R = np.diag([experiment.outputs[k].sigma ** 2 for k in names])
    written = experiment.input_at("V")
    if loop.voltage is not None:
        written = np.clip(written, -loop.voltage, loop.voltage)
    N = len(written)
    # the command at the motor over sample k: that of k - whole; before the window, the one
    # logged there (a window that cuts the log mid-run: Loop.lead_in), else 0
    lead = loop.lead_in.command if loop.lead_in is not None and loop.lead_in.command is not None else np.zeros(0)
    if loop.voltage is not None:
        lead = np.clip(lead, -loop.voltage, loop.voltage)
    prior = np.concatenate([np.zeros(max(whole + 1 - len(lead), 0)), lead[max(len(lead) - whole - 1, 0):]])
    every = np.concatenate([prior, written])          # samples -(whole + 1) .. N - 1
    B = B_now + B_before
    Q = np.outer(B, B) * INPUT_NOISE ** 2 + np.eye(n) * 1e-12
    steady = solve_discrete_are(Ad.T, C.T, Q, R)      # the a priori covariance, settled
    return dict(Ad=Ad, B_before=B_before, B_now=B_now, C=C, friction=friction, states=states, y=y, R=R, N=N,
                turns=turns,
                now=every[1:N + 1], before=every[:N], Q=Q, steady=steady)


def _setup_varying(experiment, target, values: Mapping[str, float]) -> dict:
    """:func:`_setup`'s for a log whose clock jitters: the plant sampled over each logged
    interval (``Phi``), the voltage at the motor switching where each command arrived (its
    sample's reading, plus its computing time, plus the loop's delay, as the replay applies it:
    identify/replay.py closed_loop) and what it adds over each interval (``known``), the
    process noise of each interval (the voltage's disturbance held over it)."""
    from scipy.linalg import expm, solve_discrete_are

    loop = experiment.loop
    A, B, Bt, C, states, coulomb = _linear(target, values)
    n = A.shape[0]
    names = ["theta0", "theta1"] + (["i"] if "i" in experiment.outputs and C.shape[0] > 2 else [])
    C = C[:len(names)]
    y = np.column_stack([experiment.outputs[k].values for k in names])
    turns = 2 * math.pi * round(float(np.mean(y[:, 1])) / (2 * math.pi))
    y[:, 1] -= turns
    R = np.diag([experiment.outputs[k].sigma ** 2 for k in names])
    written = experiment.input_at("V")
    lead = loop.lead_in.command if loop.lead_in is not None and loop.lead_in.command is not None else np.zeros(0)
    if loop.voltage is not None:
        written = np.clip(written, -loop.voltage, loop.voltage)
        lead = np.clip(lead, -loop.voltage, loop.voltage)
    N, h = len(written), experiment.period
    read = np.asarray(experiment.read_at, dtype=float)
    delay = experiment.loop_delay(values)
    whole = int(math.floor(delay / h + 1e-9))
    # the commands before the window, written on time at the period; the level at its start
    level = 0.0
    times, volts = [], []
    for j in range(-whole - 2, 0):
        value = float(lead[j]) if -j <= len(lead) else 0.0
        when = read[0] + j * h + delay
        if when <= read[0] + 1e-12:
            level = value
        else:
            times.append(when)
            volts.append(value)
    compute = loop.compute if loop.compute is not None else np.zeros(N)
    times = np.maximum.accumulate(np.concatenate([times, read[:N - 1] + compute[:N - 1] + delay]))
    volts = np.concatenate([volts, written[:N - 1]])
    # the intervals, each cut where a command arrives inside it
    points = np.union1d(read, times[(times > read[0]) & (times < read[-1])])
    start, end = points[:-1], points[1:]
    interval = np.clip(np.searchsorted(read, start, side="right") - 1, 0, N - 2)
    arrived = np.searchsorted(times, start + 1e-12, side="right") - 1
    held = np.where(arrived >= 0, volts[np.maximum(arrived, 0)], level)
    torques = 0 if Bt is None else Bt.shape[1]
    block = np.zeros((n + 1 + torques, n + 1 + torques))
    block[:n, :n], block[:n, n] = A, B[:, 0]
    if Bt is not None:
        block[:n, n + 1:] = Bt
    steps = np.diff(read)
    over = _flows(block, steps)   # each interval: Phi, the voltage's, the torques'
    Phi, gamma = over[:, :n, :n], over[:, :n, n]
    pieces = _flows(block[:n + 1, :n + 1], end - start)[:, :n, n]
    after = _flows(A, read[interval + 1] - end)
    known = np.zeros((N - 1, n))
    np.add.at(known, interval, np.einsum("kij,kj->ki", after, pieces) * held[:, None])
    Q = np.einsum("ki,kj->kij", gamma, gamma) * INPUT_NOISE ** 2 + np.eye(n) * 1e-12
    # the settled covariance at the typical step: the scale of a start that is not known
    Ad_h = expm(block[:n + 1, :n + 1] * h)
    g_h = Ad_h[:n, n]
    steady = solve_discrete_are(Ad_h[:n, :n].T, C.T, np.outer(g_h, g_h) * INPUT_NOISE ** 2 + np.eye(n) * 1e-12, R)
    friction = None if Bt is None else (over[:, :n, n + 1:], *coulomb)
    return dict(varying=True, Phi=Phi, known=known, Q=Q, C=C, friction=friction, states=states, y=y, R=R,
                N=N, turns=turns, steady=steady, gains={})


def _flows(M: np.ndarray, seconds: np.ndarray) -> np.ndarray:
    """expm(M * s) for each of ``seconds``, each distinct duration once (a logger's clock
    repeats its steps)."""
    from scipy.linalg import expm

    distinct, index = np.unique(seconds, return_inverse=True)
    return expm(M[None] * distinct[:, None, None])[index.reshape(-1)]


def _varying_gains(m: dict, diffuse: bool) -> dict:
    """The Kalman filter's gains K, the smoother's G and the covariances (after each reading,
    before the next) of a jittered log's model ``m`` (:func:`_setup_varying`), from a start
    ``diffuse`` or settled; kept in ``m``."""
    if diffuse in m["gains"]:
        return m["gains"][diffuse]
    Phi, Q, C, R, N = m["Phi"], m["Q"], m["C"], m["R"], m["N"]
    n = Phi.shape[1] if N > 1 else C.shape[1]
    P = DIFFUSE * m["steady"] if diffuse else m["steady"].copy()
    K, G = np.zeros((N, n, C.shape[0])), np.zeros((max(N - 1, 0), n, n))
    afters, predicted = np.zeros((N, n, n)), np.zeros((N, n, n))
    for k in range(N):
        predicted[k] = P
        K[k] = P @ C.T @ np.linalg.inv(C @ P @ C.T + R)
        afters[k] = P - K[k] @ C @ P
        if k < N - 1:
            P = Phi[k] @ afters[k] @ Phi[k].T + Q[k]
            P = 0.5 * (P + P.T)
            G[k] = afters[k] @ Phi[k].T @ np.linalg.inv(P)
    m["gains"][diffuse] = dict(K=K, G=G, afters=afters, predicted=predicted)
    return m["gains"][diffuse]


def _pass_varying(m: dict, gains: dict, start: np.ndarray, y: np.ndarray, known: np.ndarray) -> np.ndarray:
    """:func:`_pass` over a jittered log's intervals: the filter forward, the smoother back."""
    Phi, C, N = m["Phi"], m["C"], m["N"]
    K, G = gains["K"], gains["G"]
    predicted, filtered = np.zeros((N, len(start))), np.zeros((N, len(start)))
    x = start
    for k in range(N):
        predicted[k] = x
        filtered[k] = x + K[k] @ (y[k] - C @ x)
        if k < N - 1:
            x = Phi[k] @ filtered[k] + known[k]
    smoothed = filtered.copy()
    for k in range(N - 2, -1, -1):
        smoothed[k] = filtered[k] + G[k] @ (smoothed[k + 1] - predicted[k + 1])
    return smoothed


def start_covariance(experiment, target, values: Mapping[str, float]) -> tuple[list[str], np.ndarray]:
    """(the plant's linearized states: theta0, dtheta0, ..., their covariance) at the first
    sample of a balancing log as its smoother knows them from the whole log (the
    Rauch-Tung-Striebel covariance, from a diffuse start) on the plant at ``values``; the
    Coulomb friction left out."""
    m = _setup(experiment, target, values)
    return m["states"], _start_covariance(m)


def _start_covariance(m: dict) -> np.ndarray:
    """The smoothed covariance at the first sample of the log :func:`_setup` gave ``m`` for."""
    from scipy.linalg import solve_discrete_lyapunov

    if m.get("varying"):
        gains = _varying_gains(m, True)
        S = gains["afters"][-1]
        for k in range(m["N"] - 2, -1, -1):
            G = gains["G"][k]
            S = gains["afters"][k] + G @ (S - gains["predicted"][k + 1]) @ G.T
        return 0.5 * (S + S.T)

    _, smoothers, afters, followings = _gains(m["Ad"], m["C"], m["Q"], m["R"], m["steady"], m["N"],
                                              covariances=True)
    # the settled smoothed covariance S = P+ + G (S - P-) G^T, then back to the first sample
    G = smoothers[-1]
    S = solve_discrete_lyapunov(G, afters[-1] - G @ followings[-1] @ G.T)
    for k in range(len(smoothers) - 2, -1, -1):
        G = smoothers[k]
        S = afters[k] + G @ (S - followings[k]) @ G.T
    return 0.5 * (S + S.T)


def stated(experiment) -> dict[str, float]:
    """The start rates a balancing log states and the smoother may start from (rate state ->
    rad/s): none for a window cut mid-run (its loop has a lead-in) or where the fit frees one."""
    from furuta_cosim.identify.experiment import Free

    rates = {k: v for k, v in experiment.start.items() if k in ("dtheta0", "dtheta1")}
    if experiment.loop.lead_in is not None or any(isinstance(v, Free) for v in rates.values()):
        return {}
    return {k: float(v) for k, v in rates.items()}


def estimated_noise(experiment, target, values: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """The two angles' measurement errors of ``experiment`` (logged minus estimated true
    angle, rad, one value per sample), on the plant at ``values``: the smoother starts from the
    log's stated start rates where it states them (:func:`stated`), else diffuse."""
    m, smoothed = _smoothed(experiment, target, values, stated(experiment))
    angles = smoothed @ m["C"][:2].T
    return m["y"][:, 0] - angles[:, 0], m["y"][:, 1] - angles[:, 1]


def start_estimate(experiment, target, values: Mapping[str, float]) -> dict[str, tuple[float, float]]:
    """state -> (its estimate, its standard deviation) at the first sample of a balancing log,
    as the smoother knows them from the log's readings alone on the plant at ``values`` (a
    diffuse start; the pendulum's angle from upright, in the log's turn)."""
    states, first, S = start_state(experiment, target, values)
    return {name: (float(first[j]), float(math.sqrt(max(S[j, j], 0.0)))) for j, name in enumerate(states)}


def start_state(experiment, target, values: Mapping[str, float]) -> tuple[list[str], np.ndarray, np.ndarray]:
    """(the plant's linearized states, their smoothed estimate, its covariance) at the first
    sample of a balancing log from its readings alone (:func:`start_estimate`), the plant
    linearized once."""
    m = _setup(experiment, target, values)
    _, smoothed = _smoothed(experiment, target, values, {}, m)
    first = smoothed[0].copy()
    if "theta1" in m["states"]:
        first[m["states"].index("theta1")] += m["turns"]
    return m["states"], first, _start_covariance(m)


def _smoothed(experiment, target, values: Mapping[str, float],
              rates: Mapping[str, float], m: dict | None = None) -> tuple[dict, np.ndarray]:
    """(:func:`_setup`'s, the smoothed state at every sample) of ``experiment`` at ``values``:
    from ``rates`` (rate state -> rad/s) with the settled covariance, or diffuse if none; ``m``:
    :func:`_setup`'s, if already made."""
    m = _setup(experiment, target, values) if m is None else m
    C, friction, y, N = (m[k] for k in ("C", "friction", "y", "N"))
    start = np.linalg.lstsq(C, y[0], rcond=None)[0]   # the angles (and current) read, rates 0
    for name, value in rates.items():
        if name in m["states"]:
            start[m["states"].index(name)] = value
    if m.get("varying"):
        driven = m["known"]
        varying = _varying_gains(m, not rates)

        def smooth(known: np.ndarray) -> np.ndarray:
            return _pass_varying(m, varying, start, y, known)
    else:
        Ad, B_before, B_now, before, now = (m[k] for k in ("Ad", "B_before", "B_now", "before", "now"))
        gains, smoothers = _gains(Ad, C, m["Q"], m["R"], m["steady"], N, diffuse=not rates)
        driven = np.outer(before, B_before) + np.outer(now, B_now)   # what the voltage adds, per sample

        def smooth(known: np.ndarray) -> np.ndarray:
            return _pass(Ad, C, gains, smoothers, start, y, known)

    smoothed = smooth(driven)
    if friction is not None:
        # the Coulomb friction the linearization left out, added back as the joints' torques at
        # the rates of the pass before, until they settle: without it the arm's estimate drifts
        # where it reverses, and a fit through it biased C0 by a fifth; with one pass C0 still
        # came out 1.4 % low (median of the ten logs under the LQR of tools/bench_balancing.py;
        # 2.8 % at worst), with passes until the torques settle 1.0 % (2.3 %)
        Bt, rates, tc0, tc1, w_c = friction
        torque = np.zeros((N, 2))
        for _ in range(FRICTION_PASSES):
            before_pass = torque
            torque = np.column_stack([-tc0 * np.tanh(smoothed[:, rates[0]] / w_c),
                                      -tc1 * np.tanh(smoothed[:, rates[1]] / w_c)])
            if np.max(np.abs(torque - before_pass)) <= FRICTION_SETTLED * max(tc0, tc1):
                break
            added = (np.einsum("kij,kj->ki", Bt, torque[:N - 1]) if Bt.ndim == 3
                     else torque @ Bt.T)   # a jittered log's per interval (its last sample's unused)
            smoothed = smooth(driven + added)
    return m, smoothed


def _pass(Ad, C, gains, smoothers, start: np.ndarray, y: np.ndarray, known: np.ndarray) -> np.ndarray:
    """The smoothed state at every sample of the readings ``y``: the Kalman filter forward from
    ``start`` (``known``: what the inputs add over each sample), the smoother's gains back. The
    samples with gains of their own (a diffuse start settling) go one by one; from where the
    gains hold, each direction is a constant linear recursion (:func:`_recurrence`)."""
    N, n = len(y), Ad.shape[0]
    predicted, filtered = np.zeros((N, n)), np.zeros((N, n))
    x = start
    head = min(len(gains) - 1, N)          # the samples before the gains hold
    for k in range(head):
        predicted[k] = x
        filtered[k] = x + gains[k] @ (y[k] - C @ x)
        if k + 1 < N:
            x = Ad @ filtered[k] + known[k]
    if head < N:
        # filtered[k + 1] = (I - G C) (Ad filtered[k] + known[k]) + G y[k + 1]
        G = gains[-1]
        M = np.eye(n) - G @ C
        predicted[head] = x
        filtered[head] = M @ x + G @ y[head]
        drive = known[head:N - 1] @ M.T + y[head + 1:N] @ G.T
        filtered[head:] = _recurrence(M @ Ad, filtered[head], drive)
        predicted[head + 1:] = filtered[head:N - 1] @ Ad.T + known[head:N - 1]
    smoothed = filtered.copy()
    low = max(len(smoothers) - 1, 0)       # from here up, the smoother's gain holds
    if low <= N - 2:
        # smoothed[k] = S smoothed[k + 1] + (filtered[k] - S predicted[k + 1]), run backward
        S = smoothers[-1]
        drive = filtered[low:N - 1] - predicted[low + 1:N] @ S.T
        smoothed[low:] = _recurrence(S, filtered[N - 1], drive[::-1])[::-1]
    for k in range(min(low, N - 1) - 1, -1, -1):
        smoothed[k] = filtered[k] + smoothers[k] @ (smoothed[k + 1] - predicted[k + 1])
    return smoothed


def _recurrence(F: np.ndarray, first: np.ndarray, drive: np.ndarray) -> np.ndarray:
    """``x`` with ``x[0] = first`` and ``x[k + 1] = F x[k] + drive[k]`` (len(drive) + 1 rows), in
    chunks of about sqrt(len(drive)) samples: what the drive adds within each chunk, all chunks
    stepped together, then each chunk's first state in turn, then the rest in one product. Each
    product is small (no BLAS threads to contend for); a sample-by-sample loop in Python was
    most of a balancing fit's time."""
    T, n = drive.shape
    out = np.empty((T + 1, n))
    out[0] = first
    if T == 0:
        return out
    chunk = max(1, math.isqrt(T))
    chunks = -(-T // chunk)
    padded = np.zeros((chunks * chunk, n))
    padded[:T] = drive
    steps = padded.reshape(chunks, chunk, n)
    added = np.empty((chunks, chunk, n))                    # from a zero state at each chunk's start
    z = np.zeros((chunks, n))
    for i in range(chunk):
        z = z @ F.T + steps[:, i]
        added[:, i] = z
    powers = [F]
    for _ in range(chunk - 1):
        powers.append(F @ powers[-1])
    starts = np.empty((chunks, n))                          # each chunk's first state, in turn
    x = first
    for c in range(chunks):
        starts[c] = x
        x = powers[-1] @ x + added[c, -1]
    carried = np.concatenate(powers)                        # x[s] -> x[s + 1 .. s + chunk]
    out[1:] = ((starts @ carried.T).reshape(chunks * chunk, n) + added.reshape(chunks * chunk, n))[:T]
    return out


def noise_draw(experiment, target, values: Mapping[str, float], seed: int) -> tuple[np.ndarray, np.ndarray]:
    """What the smoother of ``experiment`` at ``values`` makes of reading noise alone (each
    reading's stated noise, Gaussian, drawn with ``seed``; no input, the start as the log's own
    smoother starts): the two angles' estimates (rad per sample), a draw of its estimate's error
    under its own noise model. Added to :func:`estimated_noise`, it moves what a replay's
    controller sees as the smoother's own error could (identify/reach.py)."""
    m = _setup(experiment, target, values)
    C = m["C"]
    readings = np.random.default_rng(seed).standard_normal(m["y"].shape) * np.sqrt(np.diag(m["R"]))
    if m.get("varying"):
        start = np.linalg.lstsq(C, readings[0], rcond=None)[0]
        gains = _varying_gains(m, not stated(experiment))
        angles = _pass_varying(m, gains, start, readings, np.zeros_like(m["known"])) @ C[:2].T
        return angles[:, 0], angles[:, 1]
    gains, smoothers = _gains(m["Ad"], C, m["Q"], m["R"], m["steady"], m["N"], diffuse=not stated(experiment))
    start = np.linalg.lstsq(C, readings[0], rcond=None)[0]
    angles = _pass(m["Ad"], C, gains, smoothers, start, readings, np.zeros((m["N"], m["Ad"].shape[0]))) @ C[:2].T
    return angles[:, 0], angles[:, 1]


def _gains(Ad, C, Q, R, steady, samples: int, covariances: bool = False, diffuse: bool = True) -> tuple:
    """The Kalman gains and the smoother's gains of the first samples (the last of each holds
    from there on): from a ``diffuse`` start (DIFFUSE times the settled covariance: the state at
    the log's first sample is known from its first reading alone, rates not at all), or from
    the settled covariance, until the covariance has settled to within SETTLED of ``steady``.
    With ``covariances``, also each sample's covariance after its reading and before the next."""
    P = DIFFUSE * steady if diffuse else steady
    gains, smoothers, afters, followings = [], [], [], []
    for _ in range(samples):
        gain = P @ C.T @ np.linalg.inv(C @ P @ C.T + R)
        after = P - gain @ C @ P
        following = Ad @ after @ Ad.T + Q
        gains.append(gain)
        smoothers.append(after @ Ad.T @ np.linalg.inv(following))
        afters.append(after)
        followings.append(following)
        if np.max(np.abs(following - steady)) <= SETTLED * np.max(np.abs(steady)):
            break
        P = following
    return (gains, smoothers, afters, followings) if covariances else (gains, smoothers)


def with_estimate(experiment, target):
    """``experiment`` with its loop's angles estimated in every replay (a balancing log on
    this project's plant), else as it is."""
    if target.mapping is not None or not balancing(experiment) or experiment.loop.estimate:
        return experiment
    return replace(experiment, loop=replace(experiment.loop, estimate=True))


def prepared(spec, target):
    """``spec`` as a fit replays it: each balancing log with its angles estimated, each other
    closed-loop log (a swing-up) driven by its logged voltage after the loop's delay, open loop."""
    from furuta_cosim.identify.split import delayed

    def one(experiment):
        if experiment.loop is None:
            return experiment
        if target.mapping is None and balancing(experiment):
            return with_estimate(experiment, target)
        return delayed(experiment)

    return replace(spec, experiments=tuple(one(e) for e in spec.experiments),
                   validation=tuple(one(e) for e in spec.validation))
