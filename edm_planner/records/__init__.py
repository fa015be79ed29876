"""The records layer: what the product writes down and keeps.

The plan store, the certificate digest, the plan and set exports (plan.json, set.json, meshes, CSV) and the
result plots. It sits above the domain packages (``geometry``, ``interference``, ``machine``, ``planning``,
``roughing``, ``machining``, ``process``), which know nothing of files and keep only ``to_dict``/``from_dict``
on their types, and below the entry points (``nodes``, ``cli``, ``bench``, ``apps``). The layers are a
contract checked by import-linter (``.importlinter``). No rclpy.
"""
