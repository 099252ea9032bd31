"""How much of the continuous study maps the observed route solves alone (issue 34).

A hand-written rule that reads only ``observe_route``'s direction: turn towards it (the turn command twice
the heading error in radians, as a fraction of ``w_max``: 4 rad/s per radian at the contract's 2 rad/s,
saturating there) and drive at the error's cosine (0 when facing away). It runs the evaluation's episodes
(every item, deterministic) on both study maps and prints delivery, contacts and steps per delivery (the
exact bound and the pursuit controller's: docs/continuous.md). ``python bench/investigations/continuous_route_rule.py``
(seconds). Recorded in bench/results/continuous/NOTES.md ("The route observed").

``--both-ends``: the rule drives with whichever end of the robot faces the route (backwards when the route's
forward component is negative), so it reverses out instead of turning round ("SAC against pursuit, item by item").
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import numpy as np

from wrl_jax.envs.continuous import evaluation, geodesic
from wrl_jax.envs.continuous.registration import make_named


def follow_route(base: int, both_ends: bool = False):
    """The rule, for an observation whose route values start at ``base`` (``both_ends``: either end leads)."""

    def act(obs, state):
        forward, left = obs[base], obs[base + 1]
        backwards = both_ends & (forward < 0)
        error = jnp.where(backwards, jnp.arctan2(-left, -forward), jnp.arctan2(left, forward))
        speed = jnp.clip(jnp.cos(error), 0.0, 1.0)
        return jnp.stack([jnp.where(backwards, -speed, speed), jnp.clip(2.0 * error, -1.0, 1.0)])

    return act


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--both-ends", action="store_true", help="drive backwards where the route is behind")
    args = parser.parse_args()
    for name in ("8x8", "12x12"):
        env, params = make_named(name, shaping="geodesic", observe_route=True)
        act = follow_route(env.obs_size - geodesic.ROUTE_FEATURES, args.both_ends)
        result = jax.jit(lambda p: evaluation.evaluate_episodes(act, env, p))(params)
        valid = np.asarray(result.valid)
        delivered = np.asarray(result.delivered)[valid]
        steps = np.asarray(result.steps)[valid][delivered]
        print(f"{name}: delivered {delivered.mean():.1%}, contacts {int(np.asarray(result.collisions)[valid].sum())}, "
              f"{steps.mean():.1f} steps per delivery")


if __name__ == "__main__":
    main()
