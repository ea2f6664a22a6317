"""SLAM: the path and the map together.

In data-flow order: :mod:`~bayesmap.slam.problem` (the scenes: odometry, scans, map model),
:mod:`~bayesmap.slam.poses` (the motion-model pose kernels), :mod:`~bayesmap.slam.scanmatch` (the front end),
:mod:`~bayesmap.slam.posegraph` (the back end: loop closure and the pose graph), :mod:`~bayesmap.slam.joint` (the
joint chain over poses and walls), :mod:`~bayesmap.slam.smc` (particles over poses and walls) and
:mod:`~bayesmap.slam.pipeline` (a whole log, stage by stage).
"""
