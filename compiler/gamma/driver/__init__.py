"""Driver: runs an effect on a scene with the C++ runtime and writes the outputs.

``runner`` sets a run up (scene, kernels, runtime ``Config``) and owns the
iteration loop; the loop publishes events (``events``) to writers
(``writers``: maps, renders, summary, sequence, export, progress; add yours
with ``run(effect, opts, writers=[...])``).  ``scene`` assembles meshes and
binds their parts to surfaces; ``export`` bakes textures and encodes glTF/OBJ;
``outputs`` encodes PLY, false-colour PNG and JSON; ``camera`` frames the scene.
``sweep`` runs a parameter grid as Ray tasks (``gammac sweep``) and
``distributed`` traces iterations on Ray workers (``gammac run --ray``);
``cluster`` connects to Ray, the optional extra.

The driver never looks inside rule bodies: it uses the checked effect's
declarations and the kernels' addresses.
"""

from .events import (CallbackWriter, IterationTraced, IterationUpdated, RunFinished, SetupDone,
                     Writer)
from .runner import RunError, RunOptions, run

__all__ = ["run", "RunOptions", "RunError", "Writer", "CallbackWriter", "SetupDone",
           "IterationTraced", "IterationUpdated", "RunFinished"]
