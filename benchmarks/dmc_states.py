"""SINDy from the physics state of a DeepMind Control task, planned by MPPI: the reference the
pixel models are measured against (how far sparse equations and the planner reach when the
latent is the true state).

Per seed: random-action episodes of the task (no camera: the physics state only), each hinge
angle without limits as (cos, sin); a discrete-time SINDy model of the state fitted by sparse
regression, once plainly (STLSQ) and once trimmed (:class:`~latent_sindy.sindy.Trimmed`: the
rows a smooth library explains, so a cart's end stops and other contacts do not pull the
fit); a reward head r̂(s, u) (the library's) fitted to the task's rewards; then episodes of
1000 control steps planned by MPPI against r̂ with each model, without exploration noise,
from starts of the task's own distribution that no fit saw. Prints each seed's returns, the
ratio of the trimmed fit's mean return to the plain one's, the equations of the first seed,
and the published scores at 100k environment steps for reference.

With ``--velocity difference`` the model sees the positions' change over the last control
step instead of the velocities (what two stacked frames show), with ``--previous-action``
the action held over it too, and with ``--position-noise`` a camera's error in the
positions: what a pixel latent of two frames can be at best (RESULTS.md). With ``--window``
the fit is the windowed one (each feature's change over that many control steps against
the library summed over them, :func:`~latent_sindy.sindy.fit_trajectory_data`), which a
camera's error spoils far less than the one-step fit. ``--gain`` filters what the planner
reads as the library's read-latent planner does (``auto``: the gain chosen on the training
episodes, :func:`~latent_sindy.read_latent.filter_gain`); ``--iterations`` gives
MPPI several updates a command.

    python benchmarks/dmc_states.py                               # cartpole-swingup, 5 seeds
    python benchmarks/dmc_states.py --episodes 20 --seeds 0 1 --evaluations 2
    python benchmarks/dmc_states.py --episodes 10 --velocity difference --previous-action
    python benchmarks/dmc_states.py --episodes 10 --velocity difference --previous-action \
        --position-noise 0 0.01 --window 5 --order 3
    python benchmarks/dmc_states.py --smoke          # one seed, 2 episodes, tiny MPPI (the tests)
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
import torch

from latent_sindy.script_args import parse_with_smoke

#: Published returns at 100k environment steps on cartpole-swingup (mean ± std over seeds):
#: CURL's Table 1, and DrQ's paper.
PUBLISHED = {"SAC from states": "835 ± 22", "PlaNet": "297 ± 39", "Dreamer": "326 ± 27",
             "CURL": "582 ± 146", "DrQ": "759 ± 92"}


def features(state: np.ndarray, periods: tuple) -> np.ndarray:
    """The physics state with each periodic coordinate replaced by (cos, sin)."""
    out: list[float] = []
    for value, period in zip(state, periods, strict=True):
        if period is None:
            out.append(float(value))
        else:
            angle = 2 * math.pi * float(value) / period
            out += [math.cos(angle), math.sin(angle)]
    return np.asarray(out)


def feature_names(names: tuple, periods: tuple, velocity: str = "state",
                  previous_action: int = 0) -> list[str]:
    out: list[str] = []
    half = len(names) // 2
    for i, (name, period) in enumerate(zip(names, periods, strict=True)):
        if velocity == "difference" and i >= half:
            name = f"Δ{names[i - half]} / step"
        out += [name] if period is None else [f"cos {name}", f"sin {name}"]
    return out + [f"previous u{j}" for j in range(previous_action)]


class Observer:
    """What the model sees of the physics state (positions q, then velocities q̇, as many) at
    each control step: :func:`features` of it; with ``velocity="difference"`` the velocities
    replaced by the change of q since the previous control step over its duration ``dt``
    (periodic coordinates wrapped): what two stacked frames show, the velocity averaged over
    the step; with ``previous_action`` the action held over that step appended (the
    difference depends on it, so without it the features are not a state); with ``noise``
    (a standard deviation per position) Gaussian error added to the positions read, as a
    camera's. :meth:`reset` at each start (a start's difference is 0, as a stack of one
    frame twice)."""

    def __init__(self, periods: tuple, dt: float, nu: int, velocity: str = "state",
                 previous_action: bool = False, noise: tuple[float, ...] = (),
                 seed: int = 0) -> None:
        if velocity not in ("state", "difference"):
            raise ValueError(f"velocity {velocity!r}: use state or difference")
        if (velocity == "difference" or noise) and len(periods) % 2:
            raise ValueError("a difference latent or a camera's error needs as many "
                             "velocities as positions")
        if noise and len(noise) != len(periods) // 2:
            raise ValueError(f"noise {noise}: give one standard deviation per position "
                             f"({len(periods) // 2})")
        self.periods, self.dt, self.nu = periods, dt, nu
        self.velocity, self.previous_action = velocity, previous_action
        self.noise, self.rng = np.asarray(noise, np.float64), np.random.default_rng(seed)
        self._last = None

    def read(self, states: np.ndarray) -> np.ndarray:
        """States (..., ns) as read: the positions with the camera's error, if any."""
        s = np.array(states, np.float64)
        if self.noise.size:
            s[..., :self.noise.size] += self.rng.normal(0.0, self.noise,
                                                        s[..., :self.noise.size].shape)
        return s

    def reset(self, state: np.ndarray, read: bool = True) -> np.ndarray:
        self._last = None
        return self(state, np.zeros(self.nu), read)

    def __call__(self, state: np.ndarray, action: np.ndarray, read: bool = True
                 ) -> np.ndarray:
        """The features of ``state`` reached by ``action``; ``read`` False: the state was
        already read (:meth:`read`), so no error is added again."""
        s = self.read(state) if read else np.array(state, np.float64)
        q = s[:len(s) // 2].copy()
        if self.velocity == "difference":
            d = q - (q if self._last is None else self._last)
            for i, period in enumerate(self.periods[:len(q)]):
                if period is not None:
                    d[i] = (d[i] + period / 2) % period - period / 2
            s[len(q):] = d / self.dt
        self._last = q
        f = features(s, self.periods)
        return np.concatenate([f, np.asarray(action, np.float64).reshape(-1)]
                              ) if self.previous_action else f


def smoothed(q: np.ndarray, window: int) -> np.ndarray:
    """Each column of q (T, n) replaced by a local quadratic fitted over ``window`` (odd)
    samples about each one (Savitzky–Golay; at the ends, the quadratic of the first or last
    window)."""
    if window < 3 or window % 2 == 0 or window > len(q):
        raise ValueError(f"smoothing window {window}: use an odd number from 3 to {len(q)}")
    t = np.arange(window) - window // 2
    weights = np.linalg.pinv(np.vander(t, 3))[-1]  # the fit's value at the centre
    out = np.array(q, np.float64)
    for j in range(q.shape[1]):
        out[window // 2:len(q) - window // 2, j] = np.convolve(q[:, j], weights[::-1], "valid")
        for part, at in ((slice(0, window), slice(0, window // 2)),
                         (slice(len(q) - window, len(q)), slice(len(q) - window // 2, len(q)))):
            fit = np.polyfit(np.arange(window), q[part, j], 2)
            out[at, j] = np.polyval(fit, np.arange(len(q))[at] - part.start)
    return out


def collect(env, episodes: int, steps: int, repeat: int, seed: int, observer: Observer,
            smooth: int = 0):
    """Random actions: features (E, T+1, nf), actions (E, T, nu), rewards (E, T). With the
    observer's noise, each episode's positions read with it; ``smooth`` > 1: then smoothed
    over that many control steps (:func:`smoothed`, periodic ones unwrapped), as a fit of
    recorded episodes can, before the features are taken."""
    rng = np.random.default_rng(seed)
    spec = env.action_spec()
    S, U, R = [], [], []
    env.task.random.seed(seed)
    for _ in range(episodes):
        env.reset()
        states, us, rs = [env.physics.get_state().copy()], [], []
        for _ in range(steps):
            u = rng.uniform(spec.minimum, spec.maximum, spec.shape)
            rs.append(sum(float(env.step(u).reward or 0.0) for _ in range(repeat)))
            states.append(env.physics.get_state().copy())
            us.append(u)
        states = observer.read(np.asarray(states))
        if smooth > 1:
            half = len(observer.periods) // 2
            q = states[:, :half].copy()
            for i, period in enumerate(observer.periods[:half]):
                if period is not None:
                    q[:, i] = np.unwrap(q[:, i], period=period)
            states[:, :half] = smoothed(q, smooth)
        s = [observer.reset(states[0], read=False)]
        s += [observer(states[t + 1], us[t], read=False) for t in range(steps)]
        S.append(s)
        U.append(us)
        R.append(rs)
    return np.asarray(S), np.asarray(U), np.asarray(R)


def fit_reward(Z: torch.Tensor, U: torch.Tensor, R: torch.Tensor, width: int, updates: int,
               seed: int):
    from latent_sindy.models.reward_head import RewardHead

    torch.manual_seed(seed)
    head = RewardHead(Z.shape[1], U.shape[1], width)
    opt = torch.optim.Adam(head.parameters(), lr=3e-3)
    g = torch.Generator().manual_seed(seed)
    for _ in range(updates):
        i = torch.randint(0, len(Z), (256,), generator=g)
        loss = (head(Z[i], U[i]) - R[i]).pow(2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    with torch.no_grad():
        share = float((head(Z, U) - R).pow(2).mean() / R.var())
    return head.requires_grad_(False), share


def plan(env, model, head, mppi_cfg, episodes: int, steps: int, repeat: int, seed: int,
         observer: Observer, gain: float = 1.0, circle: tuple[int, int] | None = None
         ) -> list[float]:
    """Returns of ``episodes`` MPPI episodes against the reward head, without noise; each
    step's features filtered with ``gain`` as the library's read-latent planner does."""
    from latent_sindy.control.costs import RewardCost
    from latent_sindy.control.mppi import MPPI, latent_step
    from latent_sindy.read_latent import filter_step

    spec = env.action_spec()
    low = np.broadcast_to(spec.minimum, spec.shape).tolist()
    high = np.broadcast_to(spec.maximum, spec.shape).tolist()
    returns = []
    env.task.random.seed(10_000 + seed)  # starts no fit saw
    for e in range(episodes):
        env.reset()
        mppi = MPPI(latent_step(model), RewardCost(head), mppi_cfg, low, high,
                    seed=seed * 1000 + e)
        total = 0.0
        f = observer.reset(env.physics.get_state())
        for _ in range(steps):
            u, _ = mppi.command(torch.tensor(f, dtype=torch.float32))
            u = u.numpy().astype(np.float64)
            total += sum(float(env.step(u).reward or 0.0) for _ in range(repeat))
            read = observer(env.physics.get_state(), u)
            if gain >= 1.0:  # (the reading as it is)
                f = read
                continue
            with torch.no_grad():  # the library planner's filter
                pred = model(torch.tensor(f[None], dtype=torch.float32),
                             torch.tensor(u[None], dtype=torch.float32))[0]
                f = filter_step(pred, torch.tensor(read, dtype=torch.float32),
                                torch.tensor(True), gain, circle).double().numpy()
        returns.append(total)
    return returns


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--task", default="cartpole-swingup")
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    p.add_argument("--episodes", type=int, default=80, help="random episodes to fit on")
    p.add_argument("--evaluations", type=int, default=4, help="planned episodes a seed")
    p.add_argument("--order", type=int, default=4, help="SINDy's polynomial order")
    p.add_argument("--min-share", type=float, default=0.01)
    p.add_argument("--trim", type=float, default=0.3, help="share of rows left out")
    p.add_argument("--samples", type=int, default=1000)
    p.add_argument("--horizon", type=int, default=12)
    p.add_argument("--sigma", type=float, default=0.3)
    p.add_argument("--lambda", dest="lambda_", type=float, default=0.1)
    p.add_argument("--iterations", type=int, default=1, help="MPPI updates a command")
    p.add_argument("--reward-width", type=int, default=64)
    p.add_argument("--reward-updates", type=int, default=3000)
    p.add_argument("--velocity", choices=("state", "difference"), default="state",
                   help="the velocities the model sees: the physics state's, or the "
                   "positions' change over the last control step (as two stacked frames)")
    p.add_argument("--previous-action", action="store_true", help="append the action held "
                   "over the last control step to what the model sees")
    p.add_argument("--position-noise", type=float, nargs="+", default=(), metavar="SD",
                   help="Gaussian error added to each position the model sees (one standard "
                   "deviation per position, in the state's units: metres, radians)")
    p.add_argument("--smooth", type=int, default=0, metavar="WINDOW",
                   help="smooth the positions read over this many control steps (odd) "
                   "before the fit's features are taken (the planner's stay unsmoothed)")
    p.add_argument("--window", type=int, default=1, metavar="STEPS",
                   help="fit each state's change over this many control steps to the sum of "
                   "the library over them (the windowed fit: a camera's error averages out)")
    p.add_argument("--gain", default="1", help="the planner's filter gain: a number in "
                   "(0, 1] (1, the default: each reading as it is), or auto: chosen on the "
                   "training episodes as the library's ReadLatent does (filter_gain)")
    args = parse_with_smoke(p, argv, {"seeds": [0], "episodes": 2, "evaluations": 1,
                                      "order": 2, "samples": 16, "horizon": 2,
                                      "reward_updates": 20})
    torch.set_num_threads(1)

    from latent_sindy.control.mppi import MPPIConfig
    from latent_sindy.models import SindyConfig
    from latent_sindy.read_latent import filter_gain
    from latent_sindy.sindy import STLSQ, Trimmed
    from latent_sindy.worlds.dmc.config import DmcConfig
    from latent_sindy.worlds.dmc.env import physics_names
    from latent_sindy.worlds.dmc.suite import load

    cfg = DmcConfig(task=args.task)
    repeat, steps = cfg.action_repeat, 1000 // cfg.action_repeat
    env = load(cfg)
    names, periods = physics_names(env.physics)
    nu = env.action_spec().shape[0]
    observer = Observer(periods, env.control_timestep() * repeat, nu, args.velocity,
                        args.previous_action, tuple(args.position_noise))
    fnames = feature_names(names, periods, args.velocity, nu if args.previous_action else 0)
    pairs = [i for i, n in enumerate(fnames) if n.startswith("cos ")]
    circle = (pairs[0], pairs[0] + 1) if len(pairs) == 1 else None  # (one angle's pair)
    mppi_cfg = MPPIConfig(samples=args.samples, horizon=args.horizon, sigma=args.sigma,
                          lambda_=args.lambda_, shift="repeat", iterations=args.iterations)
    print(f"{args.task} from its physics state, repeat {repeat}: {args.episodes} random "
          f"episodes ({args.episodes * steps * repeat} environment steps) a seed; SINDy order "
          f"{args.order}, min_share {args.min_share}, trimmed share {args.trim}; MPPI K "
          f"{args.samples} H {args.horizon} Σ {args.sigma} λ {args.lambda_}, {args.iterations} "
          f"update(s) a command; {args.evaluations} planned episodes a seed, no exploration noise")
    print("state: " + ", ".join(f"z{i} = {n}" for i, n in enumerate(fnames)))
    means = {"plain": [], "trimmed": []}
    for seed in args.seeds:
        t0 = time.perf_counter()
        S, U, R = collect(env, args.episodes, steps, repeat, seed, observer, args.smooth)
        # float64 for the regression: cos² + sin² = 1 makes the library's columns dependent,
        # and float32's rounding of that identity would be fitted by huge cancelling terms
        Z = torch.tensor(S[:, :-1].reshape(-1, S.shape[2]), dtype=torch.float64)
        Zn = torch.tensor(S[:, 1:].reshape(-1, S.shape[2]), dtype=torch.float64)
        Ut = torch.tensor(U.reshape(-1, U.shape[2]), dtype=torch.float64)
        Rt = torch.tensor(R.reshape(-1), dtype=torch.float32)
        head, share = fit_reward(Z.float(), Ut.float(), Rt, args.reward_width,
                                 args.reward_updates, seed)
        collect_s = time.perf_counter() - t0
        for kind in ("plain", "trimmed"):
            sparsifier = STLSQ(min_share=args.min_share)
            if kind == "trimmed":
                sparsifier = Trimmed(sparsifier, share=args.trim)
            model = SindyConfig(order=args.order, include_sine=False).build(Z.shape[1],
                                                                            Ut.shape[1])
            t1 = time.perf_counter()
            if args.window > 1:
                model.fit_trajectory_data(torch.tensor(S, dtype=torch.float64),
                                          torch.tensor(U, dtype=torch.float64), args.window,
                                          sparsifier)
            else:
                model.fit_state_data(Z, Ut, Zn, optimizer=sparsifier)
            with torch.no_grad():
                gain = float(args.gain) if args.gain != "auto" else filter_gain(
                    model.float(), torch.tensor(S, dtype=torch.float32),
                    torch.tensor(U, dtype=torch.float32),
                    torch.ones(S.shape[:2], dtype=torch.bool), circle)[0]
            fit_s = time.perf_counter() - t1
            t1 = time.perf_counter()
            returns = plan(env, model, head, mppi_cfg, args.evaluations, steps, repeat, seed,
                           observer, gain, circle)
            plan_s = time.perf_counter() - t1
            means[kind].append(float(np.mean(returns)))
            print(f"seed {seed} {kind:7s}: returns {', '.join(f'{r:.1f}' for r in returns)} "
                  f"(mean {np.mean(returns):.1f}); {model.n_active()} active terms; filter "
                  f"gain {gain}; fit "
                  f"{fit_s:.1f} s, planning {plan_s / args.evaluations:.1f} s an episode; "
                  f"data and reward head {collect_s:.1f} s (reward error {share:.4f} of its "
                  f"variance)", flush=True)
            if seed == args.seeds[0]:
                for line in model.equations():
                    print("    " + line)
    env.close()
    for kind, m in means.items():
        sd = np.std(m, ddof=1) if len(m) > 1 else float("nan")
        print(f"{kind:7s}: mean return over {len(m)} seeds {np.mean(m):.1f} (sd {sd:.1f})")
    print(f"trimmed / plain mean return: {np.mean(means['trimmed']) / np.mean(means['plain']):.2f}"
          "x")
    print("published at 100k environment steps (cartpole-swingup): "
          + "; ".join(f"{k} {v}" for k, v in PUBLISHED.items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
