"""Process tuning of workers: glibc's malloc thresholds under a dask nanny, freed memory handed back, counters."""

import os
import subprocess
import sys

import pytest

FAULTS_SCRIPT = """
import resource, sys
import numpy as np
from pipeline.engine.process import restore_malloc_defaults
if sys.argv[1] == "restore":
    restore_malloc_defaults()
x = np.ones(1 << 18)  # 2 MiB, as a frame buffer
del x
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(100):
    x = np.ones(1 << 18)  # allocated, touched, freed: from the heap, or mmapped and faulted in afresh
    del x
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


@pytest.mark.skipif(sys.platform != "linux", reason="glibc's malloc thresholds")
def test_a_dask_nanny_malloc_setting_is_undone_in_workers():
    """distributed's nanny sets MALLOC_TRIM_THRESHOLD_, which makes glibc mmap every 2 MiB buffer afresh (a page fault
    per 4 KiB touched); restore_malloc_defaults gives the heap back to such buffers."""
    env = {**os.environ, "MALLOC_TRIM_THRESHOLD_": "65536"}
    faults = {mode: int(subprocess.run([sys.executable, "-c", FAULTS_SCRIPT, mode], env=env, capture_output=True,
                                       text=True, check=True).stdout) for mode in ("as-set", "restore")}
    assert faults["as-set"] > 100 * 400  # ~512 faults per buffer
    assert faults["restore"] < faults["as-set"] / 20


@pytest.mark.skipif(sys.platform != "linux", reason="/proc/self/io and getrusage's fault counts")
def test_counters_see_a_file_read_twice_and_fresh_pages_touched(tmp_path):
    import mmap

    from pipeline.engine.process import counters_since, process_counters

    data = tmp_path / "block.bin"
    data.write_bytes(os.urandom(4 << 20))
    before = process_counters()
    for _ in range(2):  # the second read comes from the page cache: still counted, as a stage re-reading frames is
        assert len(data.read_bytes()) == 4 << 20
    pages = mmap.mmap(-1, 16 << 20)  # 16 MiB of fresh anonymous pages (4 KiB, or 2 MiB huge pages), each touched
    for at in range(0, len(pages), 4096):
        pages[at] = 1
    done = counters_since(before)
    assert done["read_bytes"] >= 8 << 20
    assert done["minor_faults"] >= 8  # at least one per huge page
    assert set(done) >= {"major_faults", "waits", "preempted", "disk_read_bytes"}
    pages.close()


TRIM_SCRIPT = """
import numpy as np
from pipeline.engine.process import release_free_memory
def rss_mb():
    return int(open("/proc/self/statm").read().split()[1]) * 4096 / 2**20
blocks = [np.ones(8192) for _ in range(4000)]  # 4,000 x 64 KiB from the heap (below the mmap threshold), touched
del blocks[:-1]  # freed, except the last, which keeps the heap's top where it is: the freed pages sit below it
held = rss_mb()
release_free_memory()
print(held, rss_mb())
"""


@pytest.mark.skipif(sys.platform != "linux", reason="glibc's malloc_trim")
def test_memory_freed_below_a_live_block_goes_back_to_the_os():
    """What a stage freed in the middle of the heap stays resident in its worker until it is trimmed."""
    held, after = map(float, subprocess.run([sys.executable, "-c", TRIM_SCRIPT], capture_output=True, text=True,
                                            check=True, env={**os.environ, "PYTHONPATH": os.getcwd()}).stdout.split())
    assert held - after > 200  # of the 250 MiB freed
