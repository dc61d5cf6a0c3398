"""policies: Stable-Baselines3 training on IcosahedronSR-v0 and sim-to-sim transfer to MuJoCo.

==========================  ==========================================================
:mod:`.hyperparams`         YAML hyperparameters keyed by env id (``hyperparams/*.yml``)
:mod:`.vec`                 an env id as one (batched) SB3 ``VecEnv``
:mod:`.train`               training runs: checkpoints, resume, TensorBoard, seeds
:mod:`.artifacts`           a policy on disk: zip, VecNormalize statistics, run record
:mod:`.evaluate`            seeded episodes, the same starts in every env
:mod:`.transfer`            identified env vs MuJoCo twin, the reference, the video
:mod:`.seeds`               several seeds of one recipe in parallel processes
:mod:`.aggregate`           IQM with bootstrap intervals over runs (rliable)
:mod:`.tuning`              Optuna search: spaces, trial objective, study, report
:mod:`.commands`            ``tensegrity-sr train``, ``transfer`` and ``tune``
==========================  ==========================================================

``SHIPPED_POLICY`` is the PPO policy trained on ``IcosahedronSR-v0`` that ships in
``policies/pretrained`` (its run record, with the exact training command, beside it).
"""

from pathlib import Path

from tensegrity_env.lazy import lazy_exports

SHIPPED_POLICY = Path(__file__).resolve().parent / "pretrained" / "ppo_IcosahedronSR-v0.zip"

_all, __getattr__ = lazy_exports(
    __name__,
    {
        "TrainResult": "policies.train",
        "EvalResult": "policies.evaluate",
        "load_policy": "policies.artifacts",
        "save_policy": "policies.artifacts",
        "LoadedPolicy": "policies.artifacts",
        "TransferResult": "policies.transfer",
        "make_training_env": "policies.vec",
    },
)
__all__ = ["SHIPPED_POLICY", *_all]
