"""The bridge to the C kernel ``native_step.h``: one package between the effects and the
engine's step.

* :mod:`~tensegrity_env.native.build`: builds and loads small C kernels once per
  machine (also used by :mod:`identification.linear.native_normal`).
* :mod:`~tensegrity_env.native.kernel`: the loaded spring-rod kernel and whether it may
  take given tensors (:func:`~tensegrity_env.native.kernel.usable_kernel`).
* :mod:`~tensegrity_env.native.pack`: :func:`~tensegrity_env.native.pack.pack_model`, the
  one adapter from a model (topology, parameters, effects) to the kernel's layout.
* :mod:`~tensegrity_env.native.engine_step`: the engine's no-gradient step by the kernel,
  with its cache of packed models and a logged reason whenever it falls back.

The kernel and the build helper sit below the effects (the ground contact's law calls
the kernel); the packing and the engine's step sit above them and below
:mod:`tensegrity_env.engine.step` and :mod:`tensegrity_env.envs`, which pass in what
they need as arguments. Names are imported on first use.
"""

from tensegrity_env.lazy import lazy_exports

__all__, __getattr__ = lazy_exports(
    __name__,
    {
        "NativeUnavailable": "tensegrity_env.native.build",
        "build_and_load": "tensegrity_env.native.build",
        "load_kernel": "tensegrity_env.native.kernel",
        "usable_kernel": "tensegrity_env.native.kernel",
        "NotNative": "tensegrity_env.native.pack",
        "PackedModel": "tensegrity_env.native.pack",
        "pack_model": "tensegrity_env.native.pack",
        "NativeEngineStep": "tensegrity_env.native.engine_step",
    },
)
