"""Programs that bring the nodes up and drive them, or prepare the machine; each runs with ``python -m``.

* :mod:`.demo` -- ``make demo``: the four nodes, one channel of the default blisk planned, a summary, plots;
* :mod:`.soak` -- ``make soak``: thousands of calls from two clients, memory and latency;
* :mod:`.crash_drill` -- a node killed mid-call and what the others do (Fast DDS transports);
* :mod:`.warmup` -- ``make setup``: every numba kernel compiled into the cache once.

Entry points: each calls :func:`edm_planner.environment.configure_process` before the core is imported.
"""
