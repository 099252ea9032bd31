"""Environment families, one folder each, and the one place that names the built-in environments.

Each line registers a name with :mod:`wrl_jax.core.registry` (and so with
gymnax as ``"wrl_jax/<name>"``); the factory module is imported only when the
name is made.
"""

from wrl_jax.core.registry import register, register_evaluation

# Each family's evaluation hook (wrl_jax.core.evaluation.FamilyEvaluation), used by the driver and the CLI.
register_evaluation("warehouse", "wrl_jax.envs.warehouse.evaluation:EVALUATION")
register_evaluation("procedural", "wrl_jax.envs.procedural.evaluation:EVALUATION")
register_evaluation("fleet", "wrl_jax.envs.fleet.evaluation:EVALUATION")
register_evaluation("continuous", "wrl_jax.envs.continuous.evaluation:EVALUATION")
register_evaluation("rware", "wrl_jax.envs.rware.evaluation:EVALUATION")

register("Warehouse-8x8-v0", "wrl_jax.envs.warehouse.registration:make_named", family="warehouse",
         map_name="8x8")
register("Warehouse-12x12-v0", "wrl_jax.envs.warehouse.registration:make_named", family="warehouse",
         map_name="12x12")
register("Fleet-12x12-v0", "wrl_jax.envs.fleet.registration:make_named", family="fleet", map_name="12x12")
register("Fleet-32x32-v0", "wrl_jax.envs.fleet.registration:make_named", family="fleet", map_name="32x32")
register("Procedural-Warehouse-v0", "wrl_jax.envs.procedural.registration:make_procedural", family="procedural")
register("Continuous-Warehouse-8x8-v0", "wrl_jax.envs.continuous.registration:make_named", family="continuous",
         map_name="8x8")
register("Continuous-Warehouse-12x12-v0", "wrl_jax.envs.continuous.registration:make_named", family="continuous",
         map_name="12x12")
register("Continuous-Warehouse-12x12-Dynamic-v0", "wrl_jax.envs.continuous.registration:make_named",
         family="continuous", map_name="12x12", dynamic=True)
register("Continuous-Procedural-Warehouse-v0", "wrl_jax.envs.continuous.procedural:make_continuous_procedural",
         family="continuous")

# rware 2.0.0's ids, as `import rware` registers them: 4 sizes x 3 request-queue sizes x 1..19 agents.
for _size in ("tiny", "small", "medium", "large"):
    for _difficulty in ("-easy", "", "-hard"):
        for _agents in range(1, 20):
            register(f"rware-{_size}-{_agents}ag{_difficulty}-v2", "wrl_jax.envs.rware.registration:make_named",
                     family="rware", size=_size, agents=_agents, difficulty=_difficulty)
del _size, _difficulty, _agents
