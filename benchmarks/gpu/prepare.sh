#!/bin/bash
# Here, before a run on a lent GPU machine (Python 3.12, JAX 0.11 with CUDA 13, no network): the wheels bayesmap
# needs that the machine's image lacks, into .whl/, and the shared logs and tools into .gpu/shared/ (both git-ignored
# through .git/info/exclude, so name them in the device tool's carry). Then, there: `source benchmarks/gpu/setup.sh`.
set -euo pipefail
cd "$(dirname "$0")/../.."
mkdir -p .git/info .whl .gpu
for p in /.whl/ /.gpu/; do grep -qx "$p" .git/info/exclude 2>/dev/null || echo "$p" >> .git/info/exclude; done
python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
  --platform manylinux_2_34_x86_64 --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 \
  --platform manylinux_2_24_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 -d .whl \
  genjax==0.10.3 penzai==0.2.5 tensorflow-probability==0.25.0 beartype==0.20.2 Deprecated==1.3.1 ordered-set \
  dm-tree==0.1.10 gast decorator rosbags==0.11.9 apsw backports.zstd lz4 ruamel.yaml
rm -rf .gpu/shared && mkdir -p .gpu/shared && cp -r ../shared/data ../shared/tools .gpu/shared/
du -sh .whl .gpu
