"""The run: what ``gammac run`` does from the effect and the scene to the last
iteration.

``runner`` sets a run up (``scene``, kernels, the runtime ``Config``:
``config``) and owns the iteration loop; ``common`` holds what the parts
share (``RunError``, the checked runtime); the loop publishes ``events`` to
writers.  ``scene`` assembles meshes (``gltf`` reads glTF, checked by
``gltf_check``) and binds their parts to surfaces; ``scene_inputs``,
``vertex_attributes`` and ``mask_atlas`` give surfels what mask() and
attribute() read.  ``camera`` frames the scene; ``folder`` keeps the output
folder whole; ``resume`` and ``layered`` start from a saved run; ``reload``
puts a saved iteration back into a simulation; ``prefetch`` and ``warmup``
start work ahead; ``budget`` checks memory; ``interrupt`` handles SIGINT and
SIGTERM.
"""
