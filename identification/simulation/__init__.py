"""MuJoCo ground truth: batched rollouts, randomized datasets, planted (undeclared) effects."""

from tensegrity_env.lazy import lazy_exports

__all__, __getattr__ = lazy_exports(
    __name__,
    {
        "GenerateSpec": "identification.simulation.generate",
        "InitialConditions": "identification.simulation.generate",
        "Truth": "identification.simulation.truth",
        "generate_dataset": "identification.simulation.generate",
        "load_truth": "identification.simulation.truth",
        "PlantSpec": "identification.simulation.planted",
        "PlantedData": "identification.simulation.planted",
        "add_measurement_noise": "identification.simulation.planted",
        "planted_dataset": "identification.simulation.planted",
        "Roller": "identification.simulation.rollout",
    },
)
