"""Driver: runs an effect on a scene with the C++ runtime and writes the outputs.

Four parts, each a package:
- ``running``: setting a run up and its iteration loop (``running.runner``), the
  scene, the camera, the output folder, resume, events, interruption;
- ``outputs``: the writers on the run's events, the encoders, export
  (glTF, OBJ, USD, texture sets) and renders of saved runs;
- ``caches``: the surfel set-up and the false-colour views kept for reruns;
- ``distributed``: Ray (tracing on workers, sweeps).
Imports go one way within the driver's modules (tests/test_architecture.py
checks that there is no cycle).  Add writers with
``run(effect, opts, writers=[...])``.

The driver never looks inside rule bodies: it uses the checked effect's
declarations and the kernels' addresses.
"""

# (the loop's package is ``running``, not ``run``: importing a subpackage
# sets the package's attribute of its name, which would hide ``run``)
_FROM = {"run": "running.runner", "RunOptions": "running.runner", "RunError": "running.runner",
         "Writer": "running.events",
         "CallbackWriter": "running.events", "SetupDone": "running.events", "IterationTraced": "running.events",
         "IterationUpdated": "running.events", "RunFinished": "running.events"}


def __getattr__(name: str):
    # imported on first use: the command line reads driver.camera's defaults
    # without loading the run loop (numpy, LLVM)
    if name in _FROM:
        from importlib import import_module

        return getattr(import_module(f".{_FROM[name]}", __name__), name)
    raise AttributeError(f"module 'gamma.driver' has no attribute '{name}'")


__all__ = ["run", "RunOptions", "RunError", "Writer", "CallbackWriter", "SetupDone",
           "IterationTraced", "IterationUpdated", "RunFinished"]
