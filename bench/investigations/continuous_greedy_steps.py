"""What a continuous-warehouse run's greedy policy does step by step (issue 34).

Loads a saved run (any learner, ``--run DIR``), plays every seed's deterministic policy on the
evaluation's episodes (every item, the evaluation's rounds and keys) and prints per seed:

- **speed**: the forward command's mean and median, the share of steps at |a0| >= 0.99, and the distance
  covered per step against the ``v_max dt`` a step allows (why SAC takes more steps than the bound);
- **contacts**: obstacle and shelf/wall contact steps per episode, how many episodes have one, and how
  contacts come in runs of consecutive steps (a run to the episode's end is a deadlock);
- **the safety stop** where the run trained with it: stop steps per episode, their runs, and how many of the
  episodes that did not deliver end in a run of stops (held by the stop to the time limit).

    python bench/investigations/continuous_greedy_steps.py --run /tmp/route/sac_default

Recorded in bench/results/continuous/NOTES.md ("SAC against Stable-Baselines3's SAC, and why SAC stays 4-6 %
over the bound"; "A larger contact penalty for PPO with moving obstacles").
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from wrl_jax import training
from wrl_jax.agents import get_spec
from wrl_jax.agents.base import config_from_dict
from wrl_jax.cli.options import EnvOptions, build
from wrl_jax.envs.continuous.evaluation import EVAL_SEED, rounds
from wrl_jax.training import checkpoint


def load_run(run: Path):
    """The run's metadata, algorithm (with its environment and overrides), trainer and seeds' runner states."""
    meta = checkpoint.read_metadata(run)
    spec = get_spec(meta["algo"])
    config = config_from_dict(spec.config_cls, meta["config"])
    algo = build(spec, config, EnvOptions(env=meta["env"], **meta.get("env_overrides", {})))
    trainer = training.Trainer(algo, meta["seeds"], training.LoopConfig(progress=False))
    runners, _ = checkpoint.load(run, trainer.template())
    return meta, algo, trainer, runners


def load(run: Path):
    """The run's algorithm and its seeds' greedy network parameters."""
    _, algo, _, runners = load_run(run)
    return algo, jax.vmap(algo.network_params)(runners)


def episode_steps(algo, network, key, item):
    """One evaluation episode's per-step record (``active`` marks the steps before it ended)."""
    env, params = algo.env, algo.env_params
    reset_key, step_key = jax.random.split(key)
    obs, state = env.reset_with(env.reset_draws(reset_key, params).replace(item_index=item), params)

    def body(carry, _):
        obs, state, done = carry
        action = algo.greedy_action(network, obs)
        obs2, state2, _, terminated, truncated, info = env.transition(
            jax.random.fold_in(step_key, state.time), state, action, params)
        record = dict(active=~done, forward=action[0], moved=jnp.linalg.norm(state2.pos - state.pos),
                      obstacle=info["hit_obstacle"] & ~done, shelf=(info["hit_shelf"] | info["hit_wall"]) & ~done,
                      stop=info.get("safety_stop", jnp.zeros((), bool)) & ~done, delivered=terminated & ~done,
                      stop_obstacle=info.get("stop_obstacle", jnp.zeros((), bool)) & ~done)
        state2 = jax.tree.map(lambda old, new: jnp.where(done, old, new), state, state2)
        return (obs2, state2, done | terminated | truncated), record

    _, record = jax.lax.scan(body, (obs, state, jnp.zeros((), bool)), None, length=int(params.max_steps))
    return record


def contact_runs(flags: np.ndarray) -> list[int]:
    """Lengths of the runs of consecutive ``True`` in each row of ``flags``."""
    runs = []
    for row in flags.reshape(-1, flags.shape[-1]).astype(int):
        edges = np.diff(np.concatenate([[0], row, [0]]))
        runs += list(np.where(edges == -1)[0] - np.where(edges == 1)[0])
    return runs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--run", type=Path, required=True, help="a training run's output directory")
    args = parser.parse_args()
    algo, networks = load(args.run)
    env, params = algo.env, algo.env_params
    num_rounds, num_items = rounds(env), int(params.items.shape[0])
    keys = jax.random.split(jax.random.PRNGKey(EVAL_SEED), num_rounds * num_items).reshape(num_rounds, num_items, -1)
    items = jnp.arange(num_items, dtype=jnp.int32)
    per_episode = jax.vmap(jax.vmap(lambda n, k, i: episode_steps(algo, n, k, i), in_axes=(None, 0, 0)),
                           in_axes=(None, 0, None))
    play = jax.jit(jax.vmap(lambda n: per_episode(n, keys, items)))
    record = jax.tree.map(np.asarray, play(networks))
    valid = (np.arange(num_items) < int(params.num_items))[None, :, None]
    step_length = float(params.v_max * params.dt)
    for s in range(record["forward"].shape[0]):
        active = record["active"][s] & valid
        forward, moved = record["forward"][s][active], record["moved"][s][active]
        obstacle, shelf = record["obstacle"][s] & valid, record["shelf"][s] & valid
        episodes = obstacle.shape[0] * int(params.num_items)
        runs = contact_runs(obstacle | shelf)
        print(f"seed {s}: forward command mean {forward.mean():+.3f}, median {np.median(forward):+.3f}, "
              f"|a0| >= 0.99 on {(np.abs(forward) >= 0.99).mean():.0%} of steps; {moved.mean():.3f} m per step "
              f"of {step_length:.3f}")
        print(f"        contacts per episode: obstacle {obstacle.sum() / episodes:.2f}, shelf or wall "
              f"{shelf.sum() / episodes:.2f}; episodes with one {(obstacle | shelf).any(-1).sum() / episodes:.0%}; "
              f"runs {len(runs)}, mean length {np.mean(runs) if runs else 0:.1f}, longest {max(runs, default=0)}")
        if env.safety_margin is not None:
            stop = record["stop"][s] & valid
            stops = contact_runs(stop)
            failed = ~record["delivered"][s].any(-1) & valid[..., 0]
            held = failed & stop[..., -1]  # still stopped at the time limit
            by_obstacle = held & record["stop_obstacle"][s][..., -1]
            print(f"        safety stops per episode {stop.sum() / episodes:.2f}; runs {len(stops)}, mean length "
                  f"{np.mean(stops) if stops else 0:.1f}, longest {max(stops, default=0)}; not delivered "
                  f"{int(failed.sum())}, of them held by the stop at the time limit {int(held.sum())} "
                  f"({int(by_obstacle.sum())} by an obstacle)")


if __name__ == "__main__":
    main()
