"""The runs layer: one job per front-end task, shared by the command line (:mod:`bayesmap.cli`) and the app
(:mod:`bayesmap.app`).

In data-flow order: :mod:`~bayesmap.runs.inputs` (reading a log or bag, the scan selection, the options that shape the
model, the size checks), then a job, :mod:`~bayesmap.runs.infer` (mapping), :mod:`~bayesmap.runs.slam` (the path and
the map) or :mod:`~bayesmap.runs.evaluate` (scores), each returning its result and summary, and
:mod:`~bayesmap.runs.outputs` (the checks of the output folder, ``--out-bag`` and ``--json`` made before any work,
and the writes, whole or not at all). A job takes ``progress``, a :data:`bayesmap.progress.ProgressCallback`, and
passes it on to the long library functions; it prints nothing.
"""
