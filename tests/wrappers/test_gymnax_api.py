"""gymnax 1.0 conformance of every registered environment (issue 12).

Parametrized over ``wrl_jax.registered_names()`` at collection time, so a new
family is checked as soon as :mod:`wrl_jax.envs` registers it. gymnax
consumers (PureJaxRL-style code, rejax, gymnax's own wrappers) rely on exactly
these properties: ``gymnax.make`` returns the default params, spaces are
callable without arguments and describe the arrays ``reset``/``step`` really
produce, ``step`` returns six values with the reached observation in
``info["final_observation"]``, truncation happens at
``params.max_steps_in_episode``, and environment objects are static ``jit``
arguments that survive ``copy.deepcopy`` and ``pickle`` (rejax deep-copies
its config, env included).

One jitted, vmapped rollout per environment (a module-scoped fixture) feeds
most checks, so each environment compiles only a few small programs.
"""

from __future__ import annotations

import copy
import importlib
import pickle

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import wrl_jax
from wrl_jax.core.gymnax_base import spaces  # gymnax.environments.spaces itself, without gymnax's environments
from wrl_jax.core.registry import GYMNAX_PREFIX

RWARE_SAMPLE = ("rware-tiny-2ag-v2",)
"""rware's 228 ids share one program per size and agent count: one of them stands for the family here
(its registry and every id are tested in tests/envs/rware/test_rware_env.py), the smallest with several
robots: the rollout's compile grows with the agent count (2 agents: 5.0 s of CPU, 4 agents: 8.8 s)."""
SAME_PROGRAM_AS = {"Continuous-Warehouse-12x12-v0": "Continuous-Warehouse-12x12-Dynamic-v0",
                   "Continuous-Warehouse-8x8-v0": "Continuous-Warehouse-12x12-Dynamic-v0",
                   "Fleet-32x32-v0": "Fleet-12x12-v0",
                   "Warehouse-8x8-v0": "Warehouse-12x12-v0"}
"""Names whose environment is the class of one checked here, with another grid size or no moving obstacles
(the same code: the obstacle arrays are empty); the family's own tests cover each setting (and
tests/wrappers/test_gymnax_clients.py runs gymnax clients on Warehouse-8x8-v0 itself)."""
NAMES = [name for name in wrl_jax.registered_names()
         if (not name.startswith("rware-") or name in RWARE_SAMPLE) and name not in SAME_PROGRAM_AS]
BATCH = 4
EXTRA_STEPS = 3
"""The rollout runs ``max_steps_in_episode + EXTRA_STEPS`` steps, so every environment passes the time limit."""


def num_robots(env) -> int | None:
    """``K`` for a multi-robot environment (its action is a ``(K,)`` vector), ``None`` for one robot.

    Detected by the ``num_robots`` attribute the fleet families expose; a
    family without it is single-robot (a scalar action).
    """
    robots = getattr(env, "num_robots", None)
    return None if robots is None else int(robots)


def sample_action(env, key: jax.Array) -> jax.Array:
    """A uniform random action of the right shape: a scalar, or one per robot."""
    space = env.action_space()
    robots = num_robots(env)
    if robots is None:
        return space.sample(key)
    return jax.vmap(space.sample)(jax.random.split(key, robots))


def tree_equal(a, b) -> bool:
    leaves_a, tree_a = jax.tree_util.tree_flatten(a)
    leaves_b, tree_b = jax.tree_util.tree_flatten(b)
    return tree_a == tree_b and all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(leaves_a, leaves_b))


class _SameStep:
    """Stands for the environment under the legacy view inside the rollout: its ``step`` is the 6-value step
    already computed there, returned when called with the very arguments (tracers) it was computed from."""

    def __init__(self, out: tuple, args: tuple):
        self.out, self.args = out, args

    def step(self, *args):
        assert len(args) == len(self.args) and all(a is b for a, b in zip(args, self.args)), "arguments not passed on"
        return self.out


def recording_transition(env, calls: list):
    """``env`` whose ``transition`` also appends ``(key, state, action, params, outputs)`` to ``calls`` (at trace
    time): its ``step`` is ``env``'s own code, and the output of the transition it calls is read from ``calls``."""
    clone = object.__new__(type(env))
    clone.__dict__.update(env.__dict__)

    def transition(key, state, action, params):
        outputs = env.transition(key, state, action, params)
        calls.append((key, state, action, params, outputs))
        return outputs

    clone.transition = transition
    return clone


def make_rollout(env, params, length: int, arity: dict):
    """``keys -> trace``: ``BATCH`` environments, random actions, ``length`` steps of ``jax.vmap(env.step)``.

    The trace holds every output a conformance check reads: the 6-value step,
    the 5-value :class:`wrl_jax.LegacyStepAPI` step on the same inputs, the
    observation the transition alone reaches (``env.transition`` with the
    first half of the split key, the base class's convention; the warehouse's
    transition ignores its key) and whether each observation lies in the
    space, all in one compiled program. The legacy view wraps
    :class:`_SameStep`, which hands it the step already computed: XLA does not
    merge two copies of a step (its loops and conditionals), and a second copy
    doubled the compile. For the same reason the reached observation is, where
    the step itself calls ``env.transition`` once with the very state, action
    and params and with the first half of the split key (the key's bits are
    compared in the program, ``reached_key_ok``), that call's own output
    (:func:`recording_transition`); otherwise an independent call. ``arity``
    receives the number of values each ``step`` returned, at trace time.
    """
    obs_space = env.observation_space(params)
    action_space = env.action_space(params)

    def one_env(key):
        reset_key, run_key = jax.random.split(key)
        obs0, state0 = env.reset(reset_key, params)

        def step(carry, key):
            _, state = carry
            action_key, step_key = jax.random.split(key)
            action = sample_action(env, action_key)
            calls: list = []
            out = recording_transition(env, calls).step(step_key, state, action, params)
            old = wrl_jax.LegacyStepAPI(_SameStep(out, (step_key, state, action, params))).step(
                step_key, state, action, params)
            arity["step"], arity["legacy"] = len(out), len(old)
            next_obs, next_state, reward, terminated, truncated, info = out
            reached_key = jax.random.split(step_key)[0]
            reached, reached_key_ok = None, jnp.bool_(True)
            if len(calls) == 1 and all(a is b for a, b in zip(calls[0][1:4], (state, action, params))):
                key_in = calls[0][0]
                if key_in is not None and key_in is not step_key and key_in.dtype == reached_key.dtype:
                    reached = calls[0][4][0]
                    reached_key_ok = jnp.array_equal(jax.random.key_data(key_in), jax.random.key_data(reached_key))
            if reached is None:  # the step draws its transition otherwise (the fleet), or with its own key or none
                reached = env.transition(reached_key, state, action, params)[0]
            record = {
                "obs": next_obs,
                "final_obs": info["final_obs"],
                "final_observation": info["final_observation"],
                "reached": reached,
                "reached_key_ok": reached_key_ok,
                "reward": reward,
                "terminated": terminated,
                "truncated": truncated,
                "action": action,
                "action_ok": jnp.all(action_space.contains(action)),
                "obs_ok": obs_space.contains(next_obs),
                "final_ok": obs_space.contains(info["final_obs"]),
                "time": getattr(next_state, "time", jnp.zeros((), jnp.int32)),
                "legacy_obs": old[0],
                "legacy_reward": old[2],
                "legacy_done": old[3],
                "legacy_terminated": old[4]["terminated"],
                "legacy_truncated": old[4]["truncated"],
            }
            return (next_obs, next_state), record

        _, trace = jax.lax.scan(step, (obs0, state0), jax.random.split(run_key, length))
        trace["obs0"], trace["obs0_ok"] = obs0, obs_space.contains(obs0)
        return trace

    return jax.jit(jax.vmap(one_env))


@pytest.fixture(scope="module")
def gymnax():
    """gymnax itself, imported by the first test that needs it rather than while pytest collects (it imports its
    twenty environments, about 1.5 s in each worker); the documented registration call, a no-op by then."""
    import gymnax
    import gymnax.wrappers

    assert set(wrl_jax.register_with_gymnax()) == {GYMNAX_PREFIX + name for name in wrl_jax.registered_names()}
    return gymnax


@pytest.fixture(scope="module", params=NAMES)
def case(request, gymnax):
    """``(name, env, params, trace)``: the gymnax-made environment and one rollout of it (numpy arrays).

    ``trace["arity"]`` holds the number of values ``step`` and the legacy view returned.
    """
    name = request.param
    env, params = gymnax.make(GYMNAX_PREFIX + name)
    assert hasattr(params, "max_steps_in_episode"), (
        f"{name}: its params have no max_steps_in_episode (gymnax's truncation length, read by rejax and wrappers)")
    length = int(params.max_steps_in_episode) + EXTRA_STEPS
    arity: dict = {}
    trace = make_rollout(env, params, length, arity)(jax.random.split(jax.random.key(0), BATCH))
    trace = jax.tree.map(np.asarray, trace)
    trace["arity"] = arity
    return name, env, params, trace


# ---------------------------------------------------------------- registration
def test_skipped_names_share_a_checked_class():
    """Each name left out as another size of a checked environment is built by that environment's class."""
    for name, checked in SAME_PROGRAM_AS.items():
        assert checked in NAMES and type(wrl_jax.make(name)[0]) is type(wrl_jax.make(checked)[0]), name


def test_names_are_registered_with_gymnax(gymnax):
    assert NAMES, "no environment registered"
    for name in NAMES:
        assert GYMNAX_PREFIX + name in gymnax.registered_envs


def test_gymnax_make_returns_default_params(case, gymnax):
    name, env, params, _ = case
    assert tree_equal(params, env.default_params)
    ours, our_params = wrl_jax.make(name)
    assert env == ours and tree_equal(params, our_params)
    assert isinstance(env, gymnax.environments.environment.Environment)
    assert isinstance(env.name, str) and env.name


def test_reloading_the_registrations_does_not_raise(gymnax):
    before = wrl_jax.registered_names()
    importlib.reload(wrl_jax.envs)
    importlib.reload(wrl_jax.envs)
    assert wrl_jax.registered_names() == before
    assert all(gymnax.registered_envs.count(GYMNAX_PREFIX + n) == 1 for n in before)


# ---------------------------------------------------------------------- spaces
def test_spaces_callable_with_and_without_params(case):
    _, env, params, _ = case
    action_space, obs_space = env.action_space(), env.observation_space()
    if isinstance(action_space, spaces.Box):  # a continuous family: num_actions is the action's length
        assert action_space.shape == (env.num_actions,)
    else:
        assert isinstance(action_space, spaces.Discrete) and action_space.n == env.num_actions
    assert isinstance(obs_space, spaces.Space)
    assert repr(env.action_space(params)) == repr(action_space)
    assert repr(env.observation_space(params)) == repr(obs_space)


def test_spaces_match_the_real_arrays(case):
    _, env, params, trace = case
    obs_space, action_space = env.observation_space(), env.action_space()
    robots = num_robots(env)
    length = int(params.max_steps_in_episode) + EXTRA_STEPS
    # vmap over BATCH, scan over time: leading axes (BATCH,) for reset, (BATCH, length) for step.
    assert trace["obs0"].shape == (BATCH, *obs_space.shape)
    for key in ("obs", "final_obs", "final_observation"):
        assert trace[key].shape == (BATCH, length, *obs_space.shape), key
        assert trace[key].dtype == np.dtype(obs_space.dtype), key
    action_shape = tuple(action_space.shape) if robots is None else (robots,)
    assert trace["action"].shape == (BATCH, length, *action_shape)
    assert trace["action"].dtype == np.dtype(action_space.dtype)
    assert trace["terminated"].dtype == np.bool_ and trace["truncated"].dtype == np.bool_
    assert np.issubdtype(trace["reward"].dtype, np.floating)
    # A single robot gets a scalar reward; a fleet gets a scalar or one per robot.
    assert trace["reward"].shape[2:] in {(), () if robots is None else action_shape}


def test_observations_lie_in_the_space(case):
    _, _, _, trace = case
    assert trace["obs0_ok"].all()
    assert trace["obs_ok"].all() and trace["final_ok"].all()
    assert trace["action_ok"].all()


# ------------------------------------------------------------------------ step
def test_final_observation_is_the_reached_one_on_auto_reset(case):
    _, _, _, trace = case
    done = trace["terminated"] | trace["truncated"]
    np.testing.assert_array_equal(trace["final_obs"], trace["final_observation"])
    np.testing.assert_array_equal(trace["final_obs"], trace["reached"])
    assert trace["reached_key_ok"].all(), "the step's transition ran with another key than the split's first half"
    # Not done: the returned observation is the reached one. Done: a fresh episode begins.
    np.testing.assert_array_equal(trace["obs"][~done], trace["final_obs"][~done])
    assert done.any(), "the rollout passes the time limit, so some step must end an episode"
    assert (trace["time"][done] == 0).all(), "after an auto-reset the state starts a new episode"
    differs = np.any(trace["obs"][done] != trace["final_obs"][done], axis=tuple(range(1, trace["obs"].ndim - 1)))
    assert differs.any(), "on auto-reset steps obs should be the new episode's, not the reached one"


def test_truncation_happens_at_max_steps_in_episode(case):
    _, _, params, trace = case
    max_steps = int(params.max_steps_in_episode)
    terminated, truncated = trace["terminated"], trace["truncated"]
    for env_index in range(BATCH):
        length = 0
        for t in range(terminated.shape[1]):
            length += 1
            if truncated[env_index, t]:
                assert length == max_steps, f"env {env_index} truncated after {length} steps, not {max_steps}"
            if length == max_steps:
                assert terminated[env_index, t] or truncated[env_index, t], "no episode ends at the time limit"
            if terminated[env_index, t] or truncated[env_index, t]:
                length = 0
    assert truncated.any(), "no truncation in a rollout longer than the time limit"


def test_step_returns_six_values_with_both_final_keys(case):
    _, _, _, trace = case
    assert trace["arity"]["step"] == 6
    # final_obs == final_observation is checked with the auto-reset semantics above.
    assert trace["final_observation"].shape == trace["final_obs"].shape


# -------------------------------------------------------------------- identity
def test_env_is_hashable_and_a_static_jit_argument(case):
    _, env, _, _ = case
    assert env == env and hash(env) == hash(env)  # noqa: PLR0124  (reflexivity is the point)
    traces = []

    def uses_env(environment, x):
        # Reads static configuration only, so the test compiles no environment code.
        traces.append(1)
        return x * environment.num_actions

    jitted = jax.jit(uses_env, static_argnums=0)
    assert int(jitted(env, 2)) == 2 * env.num_actions
    assert int(jitted(copy.deepcopy(env), 3)) == 3 * env.num_actions
    assert int(jitted(pickle.loads(pickle.dumps(env)), 4)) == 4 * env.num_actions
    assert len(traces) == 1, "an equal environment must hit the same jit cache entry"


def test_env_survives_deepcopy_and_pickle(case):
    """Both clones (``copy.deepcopy`` and a pickle round trip) reset as the original does: each clone's ``reset``
    traces to the original's program, the same jaxpr with the same constants, so it gives the same results for
    every key (the original's reset runs in the rollout), and nothing needs compiling here."""
    _, env, _, _ = case
    clones = {"deepcopy": copy.deepcopy(env), "pickle": pickle.loads(pickle.dumps(env))}
    for how, other in clones.items():
        assert other is not env, how
        assert other == env and hash(other) == hash(env), how
        assert tree_equal(other.default_params, env.default_params), how
        assert repr(other.observation_space()) == repr(env.observation_space()), how
    key = jax.random.key(8)
    original = jax.make_jaxpr(env.reset)(key)
    for how, other in clones.items():
        program = jax.make_jaxpr(other.reset)(key)
        assert str(program.jaxpr) == str(original.jaxpr), how
        assert len(program.consts) == len(original.consts) and tree_equal(program.consts, original.consts), how


# ---------------------------------------------------------------- legacy view
def test_legacy_view_returns_five_values(case):
    """The view repacks the 6-value step (its environment is :class:`_SameStep`, which checks the arguments it is
    called with): each value must land where the 5-value API puts it, with both flags in ``info``."""
    _, _, _, trace = case
    assert trace["arity"]["legacy"] == 5
    assert trace["legacy_done"].dtype == np.bool_
    np.testing.assert_array_equal(trace["legacy_done"], trace["terminated"] | trace["truncated"])
    np.testing.assert_array_equal(trace["legacy_terminated"], trace["terminated"])
    np.testing.assert_array_equal(trace["legacy_truncated"], trace["truncated"])
    np.testing.assert_array_equal(trace["legacy_obs"], trace["obs"])
    np.testing.assert_array_equal(trace["legacy_reward"], trace["reward"])
    assert trace["legacy_done"].any() and not trace["legacy_done"].all()


def test_legacy_view_is_hashable_and_survives_copies(case):
    _, env, params, _ = case
    legacy = wrl_jax.LegacyStepAPI(env)
    for other in (copy.deepcopy(legacy), pickle.loads(pickle.dumps(legacy))):
        assert other == legacy and hash(other) == hash(legacy)
        assert other.env == env
    assert legacy.name == env.name and legacy.num_actions == env.num_actions
    assert tree_equal(legacy.default_params, params)
    jitted = jax.jit(lambda view, x: x + view.num_actions, static_argnums=0)
    assert int(jitted(legacy, 1)) == int(jitted(copy.deepcopy(legacy), 1)) == 1 + env.num_actions
    assert legacy != env and wrl_jax.LegacyStepAPI(copy.deepcopy(env)) == legacy


def test_gymnax_legacy_wrapper_fails_under_deepcopy(gymnax):
    """Why :class:`wrl_jax.LegacyStepAPI` exists: gymnax 1.0.1's own 5-value wrapper cannot be deep-copied.

    Its ``__getattr__`` forwards every missing name to ``self._env``; a copy
    under construction has no ``_env`` yet, so the lookup recurses. rejax
    deep-copies its config (env included) in ``Algorithm.create``.
    """
    wrapper_class = getattr(getattr(gymnax.wrappers, "compat", None), "LegacyStepAPIWrapper", None)
    if wrapper_class is None:
        pytest.skip("this gymnax has no LegacyStepAPIWrapper")
    env, _ = wrl_jax.make(NAMES[0])
    with pytest.raises(RecursionError):
        copy.deepcopy(wrapper_class(env))
    copy.deepcopy(wrl_jax.LegacyStepAPI(env))  # ours does not raise
