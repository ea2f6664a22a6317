# There, on the lent GPU machine, from the project root: `source benchmarks/gpu/setup.sh` (after prepare.sh here).
# Installs the carried wheels into /tmp/site, puts the shared logs and tools at ../shared, sets PYTHONPATH (this
# folder's sitecustomize.py first) and makes a `bayesmap` command in /tmp/bin; JAX then sees the GPU as its default
# device.
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
mkdir -p ../shared && cp -r .gpu/shared/data .gpu/shared/tools ../shared/
export PYTHONPATH=$PWD/benchmarks/gpu:/tmp/site:$PWD/src
export XLA_PYTHON_CLIENT_PREALLOCATE=false PYTHONUNBUFFERED=1 PYTHONWARNINGS=ignore
mkdir -p /tmp/bin
printf '#!%s\nimport sys\nfrom bayesmap.__main__ import main\nsys.argv[0] = "bayesmap"\nmain()\n' "$(command -v python3)" \
  > /tmp/bin/bayesmap
chmod +x /tmp/bin/bayesmap
export PATH=/tmp/bin:$PATH
