"""The RWARE family's evaluation hook: the greedy team's episode return, as EPyMARL reports RWARE.

The training driver runs :func:`evaluate_policy` inside the compiled training loop: the greedy
(argmax) policy of every agent on :data:`TRAINING_EPISODES` fixed episodes (episode ``e`` starts
from ``split(key(EVAL_SEED), E)[e]``, so every seed and checkpoint sees the same warehouses),
each until the environment ends it (rware's 500 steps, or the inactivity limit when one is
set). EPyMARL's published RWARE returns are the sum of all agents' rewards over an episode,
with greedy actions at test time; ``eval_return`` is that number, comparable to their tables
for the same id and reward type.

*Solved* is not a return threshold: what return a good team reaches depends on the id (size,
agent count, queue). It is a criterion that means the same on every id: **every agent
delivered at least one requested shelf in every evaluation episode**, i.e. the whole team
has learned the fetch-and-deliver loop (no agent idles or loops forever). It says nothing of
how fast; compare ``eval_return`` with EPyMARL's tables for that.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from wrl_jax.core.evaluation import FamilyEvaluation, SweepColumns, SweepMetric, TrainRate
from wrl_jax.envs.rware.scripted import BLOCKED_EXPLORE, CROWD, EXPLORE, scripted_policy
from wrl_jax.envs.rware.types import NUM_ACTIONS
from wrl_jax.stats import mean_ci

EVAL_SEED = 0
TRAINING_EPISODES = 32
DEFAULT_HORIZON = 500
"""Steps of an evaluation episode when the environment sets no ``max_steps`` (rware's registered 500)."""

GreedyFn = Callable[[Any, jax.Array], jax.Array]

SOLVED_DEFINITION = (f"env steps per seed at the first periodic evaluation in which every agent delivered at least "
                     f"one requested shelf in every one of the {TRAINING_EPISODES} greedy episodes")


@struct.dataclass
class RwareEval:
    """One seed's greedy episodes: ``team_return (E,)`` float32 (summed over agents and steps),
    ``deliveries (E, N)`` int32 per agent, ``length (E,)`` int32 steps until the episode ended."""

    team_return: jax.Array
    deliveries: jax.Array
    length: jax.Array


def horizon_of(env: Any) -> int:
    """The evaluation episode's scan length (static): the default params' ``max_steps``, else 500."""
    max_steps = int(env.default_params.max_steps)
    return max_steps if max_steps > 0 else DEFAULT_HORIZON


def run_episodes(policy: Callable[..., jax.Array], env: Any, params: Any, num_episodes: int,
                 horizon: int, seed: int = EVAL_SEED, *, sees_state: bool = False) -> RwareEval:
    """``policy(obs (N, D)) -> actions (N,)`` on the fixed episodes; jittable (one scan, vmapped over episodes).

    Steps after the environment ends an episode (an inactivity limit, or a ``max_steps`` below
    ``horizon``) count nothing. With ``sees_state`` the policy is ``policy(key, state) -> actions``
    (a centralised planner such as :mod:`wrl_jax.envs.rware.scripted`): its key at step ``t`` is
    ``fold_in(fold_in(episode key, 1), t)``; the environment's keys do not change, so both kinds of
    policy meet the same warehouses and replacement draws.
    """
    if getattr(env, "msg_bits", 0):
        raise ValueError("the rware evaluation drives the 5 movement actions; msg_bits > 0 is not supported")

    def episode(key: jax.Array) -> RwareEval:
        reset_key, step_key = jax.random.split(key)
        obs, state = env.reset(reset_key, params)
        count = env.num_agents
        init = (obs, state, jnp.ones((), bool), jnp.zeros((), jnp.float32), jnp.zeros(count, jnp.int32),
                jnp.zeros((), jnp.int32))

        def act(obs: jax.Array, state: Any, t: jax.Array) -> jax.Array:
            if sees_state:
                return policy(jax.random.fold_in(jax.random.fold_in(key, 1), t), state)
            return policy(obs)

        def body(carry, t):
            obs, state, alive, team_return, deliveries, length = carry
            obs, state, reward, terminated, truncated, info = env.transition(
                jax.random.fold_in(step_key, t), state, act(obs, state, t), params)
            team_return = team_return + jnp.where(alive, reward.sum(), 0.0)
            deliveries = deliveries + (alive & info["delivered"]).astype(jnp.int32)
            length = length + alive.astype(jnp.int32)
            return (obs, state, alive & ~(terminated | truncated), team_return, deliveries, length), None

        (_, _, _, team_return, deliveries, length), _ = jax.lax.scan(body, init, jnp.arange(horizon))
        return RwareEval(team_return=team_return, deliveries=deliveries, length=length)

    return jax.vmap(episode)(jax.random.split(jax.random.key(seed), num_episodes))


def evaluate_policy(greedy_action: GreedyFn, network_params: Any, env: Any, params: Any) -> RwareEval:
    """The periodic evaluation of one seed (jittable): the greedy team on the fixed episodes."""
    return run_episodes(lambda obs: greedy_action(network_params, obs), env, params, TRAINING_EPISODES,
                        horizon_of(env))


@functools.partial(jax.jit, static_argnames=("env", "num_episodes", "horizon", "seed", "team"))
def team_episodes(env: Any, params: Any, num_episodes: int = TRAINING_EPISODES, horizon: int | None = None,
                  seed: int = EVAL_SEED, team: str = "scripted", explore: float | jax.Array = EXPLORE,
                  blocked_explore: float | jax.Array = BLOCKED_EXPLORE, crowd: float | jax.Array = CROWD) -> RwareEval:
    """The evaluation's fixed episodes (:func:`run_episodes`) with a team that sees the state.

    ``team``: ``"scripted"`` (:func:`~wrl_jax.envs.rware.scripted.scripted_actions`, the family's yardstick) or
    ``"random"`` (uniform over the 5 actions, the floor to compare with), on the same warehouses and
    replacement draws as the greedy team's. ``horizon`` defaults to the evaluation's (rware's 500).
    """
    if team == "scripted":
        policy = scripted_policy(env, params, explore, blocked_explore, crowd)
    elif team == "random":
        def policy(key, state):
            return jax.random.randint(key, (env.num_agents,), 0, NUM_ACTIONS, dtype=jnp.int32)
    else:
        raise ValueError(f"unknown team {team!r}; known: scripted, random")
    horizon = horizon_of(env) if horizon is None else horizon
    return run_episodes(policy, env, params, num_episodes, horizon, seed, sees_state=True)


def seed_summary(result: RwareEval) -> dict[str, jax.Array]:
    """Float32 scalars of one seed's evaluation (jittable); ``eval_solved`` is the family's criterion."""
    delivered = result.deliveries > 0  # (E, N)
    out = {
        "eval_return": result.team_return.mean(),
        "eval_deliveries": result.deliveries.sum(axis=-1).mean(),
        "eval_agents_delivering": delivered.mean(),
        "eval_episodes_with_delivery": jnp.any(delivered, axis=-1).mean(),
        "eval_length": result.length.mean(),
        "eval_solved": jnp.all(delivered),
    }
    return {k: jnp.asarray(v, jnp.float32) for k, v in out.items()}


def _interval(values: np.ndarray) -> dict[str, Any]:
    interval = mean_ci(np.asarray(values, np.float64).ravel())
    return {"mean": interval.mean, "ci95": [interval.low, interval.high], "n": interval.n}


def summarize(result: RwareEval, seeds: Sequence[int] | None = None) -> dict[str, Any]:
    """Plain numbers for ``summary.json``: per seed, the return with its 95 % interval over episodes, and the rest."""
    r = jax.tree.map(np.asarray, jax.device_get(result))
    num_seeds, episodes, num_agents = r.deliveries.shape
    seeds = list(range(num_seeds)) if seeds is None else [int(s) for s in seeds]
    if len(seeds) != num_seeds:
        raise ValueError(f"got {len(seeds)} seed labels for {num_seeds} evaluated seeds")
    flags = jax.device_get(jax.vmap(seed_summary)(result))
    rows = []
    for i, seed in enumerate(seeds):
        row = {"seed": seed, **{k.removeprefix("eval_"): float(v[i]) for k, v in flags.items()}}
        row["solved"] = bool(row["solved"] == 1.0)
        row["return_ci95"] = _interval(r.team_return[i])["ci95"]
        rows.append(row)
    seed_returns = r.team_return.mean(axis=1)
    return {
        "episodes": int(episodes),
        "num_agents": int(num_agents),
        "episode_seed": EVAL_SEED,
        "return": float(seed_returns.mean()),
        "return_ci95_over_seeds": _interval(seed_returns)["ci95"],
        "deliveries": float(r.deliveries.sum(axis=-1).mean()),
        "seeds_solved": sum(row["solved"] for row in rows),
        "per_seed": rows,
        "unit": "return: all agents' rewards summed over an episode (EPyMARL's RWARE return), greedy policy",
    }


def _span(ci: Sequence[float | None]) -> str:
    low, high = ci
    return "" if low is None or high is None or low == high else f" [{low:.2f}, {high:.2f}]"


def format_report(summary: dict[str, Any], label: str, convergence_steps: Sequence[int | None] | None = None,
                  study: dict[str, str] | None = None) -> str:
    """A Markdown table: the greedy team's return and deliveries, how many seeds solved it and when."""
    del study
    rows = summary["per_seed"]
    reached = [step for step in (convergence_steps or []) if step is not None]
    first = (f"median {int(np.median(reached)):,} steps ({len(reached)}/{len(convergence_steps)} seeds)"
             if reached else "never" if convergence_steps else "not measured")
    table = [
        ("agents, episodes per seed",
         f"{summary['num_agents']}, {summary['episodes']} (seed {summary['episode_seed']})"),
        ("episode return, all agents (95 % CI over seeds)",
         f"{summary['return']:.2f}{_span(summary['return_ci95_over_seeds'])}"),
        ("deliveries per episode", f"{summary['deliveries']:.2f}"),
        ("agents delivering (per episode)", f"{np.mean([r['agents_delivering'] for r in rows]):.0%}"),
        ("seeds solved (every agent delivers in every episode)", f"{summary['seeds_solved']} of {len(rows)}"),
        ("first solved", first),
    ]
    if "scripted" in summary:
        scripted = summary["scripted"]
        table.append(("scripted team, same episodes: return (95 % CI over episodes), deliveries",
                      f"{scripted['return']:.2f}{_span(scripted['return_ci95'])}, {scripted['deliveries']:.2f}"))
    return "\n".join([f"| {label} | |", "|---|---|", *(f"| {name} | {value} |" for name, value in table)])


def format_details(summary: dict[str, Any]) -> str:
    """Per seed: return [95 % CI over episodes], deliveries, agents delivering, episode length, solved."""
    lines = ["| seed | return [95 % CI over episodes] | deliveries | agents delivering | length | solved |",
             "|---|---|---|---|---|---|"]
    for row in summary["per_seed"]:
        lines.append(f"| {row['seed']} | {row['return']:.2f}{_span(row['return_ci95'])} | {row['deliveries']:.2f} | "
                     f"{row['agents_delivering']:.0%} | {row['length']:.0f} | {'yes' if row['solved'] else 'no'} |")
    return "\n".join(lines)


def final_report(context: Any) -> dict[str, Any]:
    """After training: the scripted team (:mod:`~wrl_jax.envs.rware.scripted`, the family's yardstick) on the
    evaluation's episodes, the same warehouses and replacement draws the greedy team met; the report prints it
    beside the learned team's return."""
    result = jax.device_get(team_episodes(context.env, context.params))
    returns = np.asarray(result.team_return, np.float64)
    return {"scripted": {"return": float(returns.mean()), "return_ci95": _interval(returns)["ci95"],
                         "deliveries": float(np.asarray(result.deliveries).sum(axis=-1).mean())}}


EVALUATION = FamilyEvaluation(
    evaluate_policy=evaluate_policy,
    seed_summary=seed_summary,
    solved_key="eval_solved",
    solved_definition=SOLVED_DEFINITION,
    summarize=summarize,
    format_report=format_report,
    format_details=format_details,
    final_report=final_report,
    progress_metric=("eval_return", "eval return"),
    progress_percent=False,
    train_rates=(TrainRate("train_throughput", "deliveries per step (training)", "deliveries_sum", per="step"),),
    sweep_columns=SweepColumns(
        metrics=(
            SweepMetric("return", "greedy return", digits=2, plot="episode return, all agents (greedy)"),
            SweepMetric("deliveries", "deliveries /episode", digits=2),
            SweepMetric("agents_delivering", "agents delivering", "percent", plot="agents delivering (%)"),
            SweepMetric("solved", "seeds solved", "solved"),
        ),
        train=(SweepMetric("mean_return", "train return (last log)", digits=2),),
        convergence_label="first solved step",
    ),
)
"""The RWARE family's evaluation hook (:mod:`wrl_jax.core.evaluation`)."""
