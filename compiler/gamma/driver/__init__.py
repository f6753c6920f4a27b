"""Driver: runs an effect on a scene with the C++ runtime and writes the outputs.

``runner`` sets a run up (scene, kernels, runtime ``Config``: ``config``)
and owns the iteration loop; ``common`` holds what the parts below it share
(``RunError``, the checked runtime); the loop publishes events (``events``) to writers
(``writers``: maps, renders, summary, sequence, export, progress; add yours
with ``run(effect, opts, writers=[...])``).  ``scene`` assembles meshes and
binds their parts to surfaces; ``export`` bakes textures and encodes glTF/OBJ;
``outputs`` encodes PLY, false-colour PNG and JSON; ``camera`` frames the scene.
``saved`` renders and exports a saved run, ``reload`` puts a saved
iteration back into a simulation.  ``sweep`` runs a parameter grid as Ray tasks (``gammac sweep``) and
``distributed`` traces iterations on Ray workers (``gammac run --ray``);
``cluster`` connects to Ray, the optional extra.

The driver never looks inside rule bodies: it uses the checked effect's
declarations and the kernels' addresses.
"""

_FROM = {"run": "runner", "RunOptions": "runner", "RunError": "runner", "Writer": "events",
         "CallbackWriter": "events", "SetupDone": "events", "IterationTraced": "events",
         "IterationUpdated": "events", "RunFinished": "events"}


def __getattr__(name: str):
    # imported on first use: the command line reads driver.camera's defaults
    # without loading the run loop (numpy, LLVM)
    if name in _FROM:
        from importlib import import_module

        return getattr(import_module(f".{_FROM[name]}", __name__), name)
    raise AttributeError(f"module 'gamma.driver' has no attribute '{name}'")


__all__ = ["run", "RunOptions", "RunError", "Writer", "CallbackWriter", "SetupDone",
           "IterationTraced", "IterationUpdated", "RunFinished"]
