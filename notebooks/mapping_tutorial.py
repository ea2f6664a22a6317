# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # Occupancy-grid mapping by Bayesian inference, with bayesmap
#
# The GenJAX mapping tutorial, told with bayesmap's API: a robot at a known position casts range rays; each
# reading is Normal around the distance to the first wall along the ray; walls are a priori independent coin flips.
# We infer which cells are walls: importance sampling (which collapses), Gibbs sampling in three orders, the
# low-prior failure of single-site Gibbs and its fix by 2x2 block Gibbs, the fast samplers, and a real laser scan.
#
# Run it with `make notebook` (renders `notebooks/mapping_tutorial.html`); the test suite executes it headless.

# %%
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from IPython.display import Image, display

import bayesmap as bm


def show(fig):
    """Display a matplotlib Figure as a PNG (works in any notebook front end and in the HTML export)."""
    display(Image(bm.figure_bytes(fig, "png")))


# %% [markdown]
# ## The map and the sensor
#
# `walls[i, j]` is 1 for a wall; `i` runs along x and `j` along y. The ASCII file shows line `i`, character `j`.

# %%
walls = bm.tutorial_map()
print(bm.format_map(walls))
problem = bm.tutorial_problem()  # the tutorial's scene: sensor at (10, 10), 100 beams, readings from key 0
grid, pos, beam_angles = problem.grid, problem.pos, problem.beam_angles
print(f"grid {grid.shape}, sensor at {pos}, {len(beam_angles)} beams, {int(walls.sum())} wall cells")

# %% [markdown]
# ## The prior: independent coin flips

# %%
prior = bm.walls_prior(grid.shape)
keys = jax.random.split(jax.random.key(1), 3)
samples = [np.asarray(jax.jit(prior.simulate)(k, (0.5,)).get_retval()) for k in keys]
for k, sample in enumerate(samples):
    print(f"prior sample {k}: {sample.mean():.2f} of the cells are walls")
show(bm.plot_map(grid, samples[0], title="A sample from the prior (prior_wall_prob = 0.5)"))

# %% [markdown]
# ## A structured prior: walls are connected
#
# The tutorial suggests a prior in which wall cells are likely connected. `bayesmap.model.prior` gives one, a
# 4-neighbour Markov random field (Ising; Geman & Geman 1984): each pair of cells that share an edge and agree
# (both walls or both free) adds a coupling `J` to the log-probability. `J = 0` is the coin flips above. The GenJAX
# model gets it exactly, through an observed auxiliary address `"connections"` (`bm.make_params(coupling=J)`).
# Its normalizing constant is unknown, so `bm.sample_prior` draws maps with a Gibbs chain on the prior alone
# (checkerboard sweeps, many of them). Near the Ising model's critical coupling (`J` about 0.88 with
# `prior_wall_prob = 0.5`) walls come in large connected regions; with a lower `prior_wall_prob` the field wins and
# the samples are nearly empty: a pairwise prior on cells makes walls clump, it does not draw thin room outlines.

# %%
structured = np.asarray(bm.sample_prior(jax.random.key(1), grid.shape, 0.5, 0.8, sweeps=1000, num_samples=3))
show(bm.plot_prior_samples(grid, np.concatenate([np.stack(samples[:1]), structured]),
                           titles=["independent (J = 0)"] + [f"MRF J = 0.8, sample {k}" for k in range(3)],
                           suptitle="Samples from the prior: coin flips and the structured prior"))

# %% [markdown]
# ## The sensor model: exact distances, then noisy readings

# %%
exact = np.asarray(bm.sensor_distances(walls, pos, beam_angles))
readings = problem.readings
print(f"exact distances {exact.min():.2f} to {exact.max():.2f} m; "
      f"readings differ by {np.abs(readings - exact).std():.3f} m (sensor_noise = {problem.params.sensor_noise})")
show(bm.plot_map(grid, walls, pos=pos, beam_angles=beam_angles, readings=readings,
                 title="The map, the rays and the readings"))
show(bm.plot_map(grid, None, pos=pos, beam_angles=beam_angles, readings=readings, title="What the robot sees"))

# %% [markdown]
# ## The full model
#
# Addresses `"walls"` and `"readings"`. Its log joint (GenJAX `assess`) scores a map against the readings.

# %%
joint_walls, joint_readings = bm.simulate(jax.random.key(2), pos, problem.params)
print(f"a joint sample: {int(np.sum(joint_walls))} wall cells, readings {np.asarray(joint_readings)[:4].round(2)} ...")
print(f"log joint of the true map: {float(bm.log_joint(walls, readings, pos, problem.params)):.1f}")
print(f"log joint of an empty map: {float(bm.log_joint(np.zeros(grid.shape), readings, pos, problem.params)):.1f}")

# %% [markdown]
# ## Importance sampling collapses
#
# Propose maps from the prior, weight them by the likelihood: with 441 cells, one particle takes all the weight.

# %%
result = bm.importance_sampling(jax.random.key(3), readings, pos, problem.params, num_particles=2000)
picked = np.asarray(bm.resample(jax.random.key(4), result.log_weights, 100))
print(f"effective sample size {float(result.ess):.2f} of 2,000; "
      f"{len(np.unique(picked))} distinct particle(s) among 100 resampled")
best = np.asarray(result.walls[picked[0]])
print(f"the best particle has {int((best != walls).sum())} of 441 cells wrong")
show(bm.plot_importance(np.asarray(result.log_weights), float(result.ess)))

# %% [markdown]
# ## Gibbs sampling, as in the tutorial
#
# The tutorial's Gibbs sweep visits every cell and scores both values with two `assess` calls. bayesmap keeps
# those samplers (`reference-*`) and adds fast ones with exactly the same conditionals. Chains start from the
# empty map; `wrong` counts the visible cells (crossed by a ray before its first true wall, or that wall) the
# posterior mean gets wrong.

# %%
def run(problem, sampler, sweeps, seed=0):
    start = time.perf_counter()
    chain = bm.run_chain(jax.random.key(seed), bm.make_sampler(problem, sampler), jnp.zeros(grid.shape), sweeps)
    samples = np.asarray(chain.samples)
    seconds = time.perf_counter() - start
    mean = bm.posterior_mean(samples, sweeps // 2)
    print(f"{sampler:24s} {sweeps:4d} sweeps  {seconds:6.2f} s (compile included)  "
          f"wrong visible cells: {problem.wrong_visible_cells(mean)} of {int(problem.visible.sum())}")
    return samples, mean


reference = {name: run(problem, name, 20)
             for name in ["reference-raster", "reference-incremental", "reference-outward"]}
show(bm.plot_posterior(grid, reference["reference-raster"][1], truth=walls, pos=pos,
                    title="Single-site Gibbs (tutorial's algorithm), 20 sweeps"))

# %% [markdown]
# ## A low prior: single-site Gibbs gets stuck, 2x2 blocks do not
#
# At `prior_wall_prob = 0.05` a lone wall cell is expensive, and the readings only improve once a whole wall
# segment is in place: single-site Gibbs cannot get there one cell at a time. Updating 2x2 blocks jointly can.

# %%
low = bm.tutorial_problem(prior_wall_prob=0.05)
stuck = run(low, "raster", 100)
blocks = run(low, "block", 100)
print(f"true map log joint {float(bm.log_joint(walls, readings, pos, low.params)):.1f}; last raster sample "
      f"{float(bm.log_joint(stuck[0][-1], readings, pos, low.params)):.1f}; last block sample "
      f"{float(bm.log_joint(blocks[0][-1], readings, pos, low.params)):.1f}")
show(bm.plot_posterior(grid, stuck[1], truth=walls, pos=pos, title="prior 0.05: single-site Gibbs, 100 sweeps"))
show(bm.plot_posterior(grid, blocks[1], truth=walls, pos=pos, title="prior 0.05: 2x2 block Gibbs, 100 sweeps"))
both = np.stack([stuck[0], blocks[0]])  # (2 chains, 100 sweeps, nx, ny)
show(bm.plot_convergence(bm.chain_log_joints(low, both), bm.chain_wrong_cells(low, both), burn_in=50,
                      truth_log_joint=float(bm.log_joint(walls, readings, pos, low.params)),
                      title="prior 0.05: chain 0 single-site, chain 1 2x2 blocks"))

# %% [markdown]
# The block chain as an animation (the sample after each sweep, and the running mean):

# %%
display(Image(bm.chain_gif(grid, blocks[0], truth=walls, pos=pos, max_frames=40), format="gif"))

# %% [markdown]
# The tutorial's own 2x2 block sweep (`reference-block`) takes 16 `assess` calls per block; a few sweeps suffice:

# %%
_ = run(low, "reference-block", 8)

# %% [markdown]
# ## The fast samplers
#
# For fixed poses, a ray-cell table lists the cells each ray crosses and where it would stop; a cell's conditional
# needs only its rays. Conflict-free cells are updated at once. Same conditionals, hundreds of times faster
# (`bayesmap bench` measures it side by side):

# %%
for name in ["raster", "outward", "block", "chromatic", "chromatic-block"]:
    _ = run(problem, name, 100)

# %% [markdown]
# Many chains at once (`vmap`) give per-cell split R-hat and effective sample size:

# %%
chains = bm.run_chains(jax.random.key(5), bm.make_sampler(problem, "block"), jnp.zeros(grid.shape), 100, 8)
diag = bm.cell_diagnostics(np.asarray(chains.samples), burn_in=50)
varying = np.isfinite(diag["r_hat"])
print(f"8 chains x 100 sweeps: worst split R-hat {np.nanmax(diag['r_hat']):.3f}, smallest ESS "
      f"{np.nanmin(diag['ess']):.0f} over the {int(varying.sum())} cells that change")
mean = bm.posterior_mean(np.asarray(chains.samples), 50)
show(bm.plot_posterior(grid, mean, truth=walls, pos=pos, std=True,
                       title="8 chains of 2x2 block Gibbs: mean and spread"))

# %% [markdown]
# ## A real laser scan
#
# One scan of the Intel Research Lab log (CARMEN format), mapped on a 0.1 m grid. Max-range readings mean "no wall
# within max range along this beam".

# %%
# the shared data beside the checkout, from the notebooks folder or from the checkout itself
candidates = [Path(f"{up}/shared/data/carmen/intel-corrected.log.gz") for up in ("../..", "..")]
log_path = next((p for p in candidates if p.exists()), None)
if log_path is None:
    print("the shared Intel log is not here; skipping the real scan")
else:
    scan = bm.scan_problem(bm.read_carmen(log_path), 100, resolution=0.1, sensor_noise=0.05)
    start = time.perf_counter()
    chain = bm.run_chain(jax.random.key(6), bm.make_sampler(scan, "chromatic"), jnp.zeros(scan.grid.shape), 40)
    print(f"scan 100: grid {scan.grid.shape} at 0.1 m, {len(scan.readings)} beams, 40 sweeps in "
          f"{time.perf_counter() - start:.1f} s")
    show(bm.plot_posterior(scan.grid, bm.posterior_mean(np.asarray(chain.samples), 20), pos=scan.pos,
                           beam_angles=scan.beam_angles, readings=scan.readings, max_range_mask=scan.max_range_mask,
                           title="Intel scan 100: P(wall)"))
