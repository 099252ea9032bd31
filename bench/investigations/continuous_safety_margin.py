"""How safe the safety stop is at each margin (issue 34; docs/continuous.md, "A safety stop under the policy").

States are drawn next to things on the 12x12 map with 4 moving obstacles: the robot anywhere it fits, obstacle 0
within 0.9 m of it, full speed forwards or backwards and any turn. For each margin, over the states that fit:
how many steps collide without the stop, how many still collide through it (a shelf corner between two rays), and
how many it stops that would not have collided, and how far a stopped robot still moves. ``--randomize``: the
contract's domain randomization (drawn gains, actuation noise), which the stop reads from the step's draws.

    python bench/investigations/continuous_safety_margin.py --draws 100000 [--randomize]

``tests/envs/continuous/test_continuous_safety.py`` asserts the default margin on 20,000 draws with these functions;
the table is in bench/results/continuous/NOTES.md ("A safety stop under the policy").
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import numpy as np

from wrl_jax.envs.continuous.dynamics import transition_core
from wrl_jax.envs.continuous.geometry import hits_shelf, hits_wall, norm
from wrl_jax.envs.continuous.registration import make_continuous
from wrl_jax.envs.continuous.safety import safety_stop
from wrl_jax.envs.warehouse.maps import WAREHOUSE_12X12


def near_miss(env, params, key):
    """A state with the robot anywhere it fits, obstacle 0 near it, and an action at full speed."""
    k_reset, k_pos, k_theta, k_action, k_obstacle = jax.random.split(key, 5)
    _, state = env.reset(k_reset, params)
    height, width = params.shelves.shape
    pos = jax.random.uniform(k_pos, (2,), maxval=jnp.array([width, height], jnp.float32))
    obstacles = state.obstacle_pos.at[0].set(pos + jax.random.uniform(k_obstacle, (2,), minval=-0.9, maxval=0.9))
    state = state.replace(pos=pos, theta=jax.random.uniform(k_theta, (), minval=-np.pi, maxval=np.pi),
                          obstacle_pos=obstacles)
    action = jax.random.uniform(k_action, (2,), minval=-1.0, maxval=1.0)
    action = action.at[0].set(jnp.sign(action[0]))
    fits = (~hits_shelf(pos, params.robot_radius, params.shelves) & ~hits_wall(pos, params.robot_radius, width, height)
            & jnp.all(norm(pos[None] - obstacles) >= params.robot_radius + params.obstacle_radius))
    return state, action, fits


def collisions_through(env, params, margin, count=20_000, seed=7) -> dict[str, int | float]:
    """Counts over ``count`` draws: states that ``fit``, collisions ``before`` the stop and ``after`` it, ``stops``,
    and ``needless`` stops (of steps that would not have collided); and ``creep``, the farthest a stopped robot
    moved (metres; randomized gains and noise are cancelled, not zeroed). With ``params.randomize`` the states carry
    drawn gains and the steps their actuation noise."""

    def one(key):
        state, action, fits = near_miss(env, params, key)
        draws = env.step_draws(key, params)
        filtered, by_obstacle, by_shelf = safety_stop(state, action, draws.noise, env.num_rays, margin, params)
        before = transition_core(state, action, draws, params)[-1]["collision"]
        _, reached, *_, info = transition_core(state, filtered, draws, params)
        stopped = by_obstacle | by_shelf
        return dict(fits=fits, before=fits & before, after=fits & info["collision"], stops=fits & stopped,
                    needless=fits & stopped & ~before, creep=jnp.where(fits & stopped, norm(reached.pos - state.pos), 0))

    out = jax.device_get(jax.jit(jax.vmap(one))(jax.random.split(jax.random.key(seed), count)))
    return {name: float(value.max()) if name == "creep" else int(value.sum()) for name, value in out.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--draws", type=int, default=100_000)
    parser.add_argument("--margins", type=float, nargs="+", default=[0.0, 0.02, 0.05, 0.1])
    parser.add_argument("--randomize", action="store_true", help="drawn gains and actuation noise (the contract's ranges)")
    args = parser.parse_args()
    env, params = make_continuous(WAREHOUSE_12X12, num_obstacles=4, randomize=args.randomize)
    print("| margin (m) | states that fit | collisions without the stop | through it | stops | needless stops | "
          "farthest a stopped robot moved (m) |")
    print("|---|---|---|---|---|---|---|")
    for margin in args.margins:
        c = collisions_through(env, params, margin, args.draws)
        print(f"| {margin:g} | {c['fits']:,} | {c['before']:,} | {c['after']:,} | {c['stops']:,} | {c['needless']:,} | "
              f"{c['creep']:.2g} |")


if __name__ == "__main__":
    main()
