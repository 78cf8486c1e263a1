"""A synthetic worker: app nodes that burn CPU when ``catanc run`` triggers them.

::

    python -m catanc.runtime.worker --node NAME [--node NAME2 ...]
        (--compute-ms MS | --modes W:MS,... | --workload SPEC [--clock-start-ns NS])
        [--seed N] [--scale-after S:FACTOR] [--record FILE] [--socket PATH] [--executor NAME,NAME ...]

One thread per node, each a :class:`catanc.client.Node` loop.  On each
trigger a node burns its compute time, measured in thread CPU time (so being
preempted does not shorten the work), then reports done.  ``--modes
"0.8:1,0.2:12"`` makes a multimodal node: 1 ms with weight 0.8, 12 ms with
weight 0.2, drawn with a generator seeded from ``--seed`` and the node name.
``--compute-ms`` or ``--modes`` given once applies to every node; given once
per ``--node``, the i-th applies to the i-th node (:func:`worker_command`
writes them next to their node).  ``--scale-after 5:3`` multiplies the
compute time by 3 for every run that starts 5 s (wall time) or more after
its node registered.  The socket defaults to ``$CATANC_SOCKET``.

``--workload SPEC`` draws every run's compute time from the spec's workload
model instead (:class:`catanc.model.workload.ComputeSampler`, seeded with
``--seed``: jitter, growth over time, spikes; each node must be a scheduled
node of SPEC), at ``at_s`` = seconds since ``--clock-start-ns``, an instant
on ``CLOCK_MONOTONIC`` (``time.monotonic_ns()``), which every process of a
run can share (default: when the worker started).  ``--record FILE`` writes
every run, as :class:`RunRecord` JSON lines, to FILE when the worker exits
(:func:`read_records` reads them back): ``catanc bench`` measures chains from
these timestamps.

``--executor A,B`` says that nodes A and B of this worker share one
single-threaded executor (the spec's ``executors``, docs/explanation/model.md section
6): their runs take turns, one at a time in the order their triggers
arrived, as a ROS executor's callbacks do; a run waiting for its turn has
not started (its record starts when its turn comes).  Each node keeps its
own thread, the one the enforcer pins and measures.

The worker exits 0 when the enforcer says stop and on SIGINT or SIGTERM
(each node says bye), 1 if a node cannot register or loses the enforcer.

Python threads share one interpreter lock, so nodes of one worker never
compute at the same time: give nodes that should run in parallel a worker
each.

The package: :mod:`.command` builds a worker's argv, :mod:`.options` parses it, :mod:`.process` runs
the node threads, :mod:`.draws` says what each run burns, :mod:`.burn` burns it, :mod:`.records`
writes and reads the runs.
"""
