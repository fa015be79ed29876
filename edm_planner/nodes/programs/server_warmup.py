"""Imported last by the nodes' fork server (:mod:`.bringup`): one-time work of a process, done once for all nodes.

- rclpy's logger finds the file of each logging call with :func:`inspect.getframeinfo`, whose first call in a
  process maps every loaded module to its file: about 0.2 s of CPU with the nodes' 1 800 modules loaded, in
  every node at its first log line, four nodes at once on two cores.
- numba fills its CPU target's registries (the typing and lowering of every builtin, about 200 modules) on
  the first kernel a process compiles or loads from its cache: 0.3 s of CPU, in every node at its first
  request that runs a kernel (the interference checker's first CheckInterference, the planner's first plan).

Done here, after the nodes' imports, each forked node starts with both (a module it imports later is added on
its first lookup, as usual). No kernel runs here: numba's thread pool starts in the node, after the fork.
Nothing here depends on the environment a node is started with (numba read its configuration when the
nodes' modules imported it, in this process).
"""

import inspect

from numba.core.registry import cpu_target

cpu_target.target_context.refresh()              # first: it imports modules the map below then holds
inspect.getframeinfo(inspect.currentframe())
