"""Imported last by the nodes' fork server (:mod:`.bringup`): one-time work of a process, done once for all nodes.

rclpy's logger finds the file of each logging call with :func:`inspect.getframeinfo`, whose first call in a
process maps every loaded module to its file: about 0.2 s of CPU with the nodes' 1 800 modules loaded, in
every node at its first log line, four nodes at once on two cores. Done here, after the nodes' imports,
each forked node starts with the map (a module it imports later is added on its first lookup, as usual).
Nothing here depends on the environment a node is started with.
"""

import inspect

inspect.getframeinfo(inspect.currentframe())
