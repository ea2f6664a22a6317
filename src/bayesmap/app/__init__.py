"""The interactive map explorer: a local web app (NiceGUI) for the tutorial's scene (``bayesmap app``).

It does what the tutorial's final interactive widget does, offline and without Jupyter:

* the grid with the true walls; a click toggles a wall, click-and-drag paints (walls or free space, whichever the
  first cell became); the sensor is a handle that can be dragged (no wall can be drawn on its cell, and it cannot be
  dropped on a wall);
* the beams and the noisy range readings, simulated from the model and redrawn whenever the walls, the sensor, the
  sensor noise or the number of beams change;
* sliders (each with a field to type a value) for ``prior_wall_prob``, ``sensor_noise``, ``num_angles`` and the
  number of sweeps;
* buttons Run inference (fast 2x2 block Gibbs in a worker thread, with a progress bar; a click while a run is going
  does nothing), Clear walls, Clear inferred walls; load an ASCII map file and save the drawn map;
* after a run, a sample slider and a "show average" switch; the inferred walls drawn as cell opacity (the tutorial's
  style) or as a heatmap;
* a path mode: clicks on free cells append sensor poses to a path (headings towards the next pose); Run SLAM
  simulates odometry (:func:`bayesmap.slam.problem.simulate_odometry`) and readings along it and runs the joint chain
  (:func:`bayesmap.runs.slam.run_simulated_slam`), then draws the posterior map, the odometry, the pose samples, the
  posterior mean path and the ATE of the mean and of the odometry.

Each browser tab gets its own :class:`~bayesmap.app.explorer.Explorer`, so tabs are independent sessions. The page's
scripts and styles are NiceGUI's own, served by the app itself: nothing is fetched from the network.

Modules: :mod:`~bayesmap.app.explorer` (the state, plain Python, tested without a browser; its runs go through
:mod:`bayesmap.runs`), :mod:`~bayesmap.app.svg` (its drawing), :mod:`~bayesmap.app.page` (the NiceGUI page, wired to
the explorer, and :func:`~bayesmap.app.page.run_app`, the server).
"""

from bayesmap.app.explorer import SAMPLER, SETTINGS, SLAM_MAX_SWEEPS, Explorer, Setting, SlamRun
from bayesmap.app.page import ExplorerPage, build_page, run_app

__all__ = ["SAMPLER", "SETTINGS", "SLAM_MAX_SWEEPS", "Explorer", "ExplorerPage", "Setting", "SlamRun", "build_page",
           "run_app"]
