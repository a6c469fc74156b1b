"""pipeline/allocator.py: large freed blocks stay in the heap, so allocating one again maps no new pages."""

import subprocess
import sys

import torch

from pipeline.allocator import keep_freed_memory

BLOCK = 64 << 20  # bytes: above glibc's largest automatic mmap threshold (32 MB)
PAGES = BLOCK // 4096

FAULTS = f"""
import resource, torch
{{setup}}
def faults():
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    block = torch.zeros({BLOCK // 4}, dtype=torch.float32)
    del block
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before
faults()
print(faults())
"""


def second_allocation_faults(setup: str) -> int:
    """Page faults of allocating a 64 MB zeroed tensor again after one was freed, in a fresh process."""
    out = subprocess.run([sys.executable, "-c", FAULTS.format(setup=setup)], capture_output=True, text=True, check=True)
    return int(out.stdout.split()[-1])


def test_a_freed_large_block_is_reused_without_new_pages():
    """Importing the harness keeps freed blocks: the second 64 MB allocation maps (almost) no new page, where a
    process without it maps every page again."""
    assert keep_freed_memory() is True  # this machine's C library is glibc
    kept = second_allocation_faults("import pipeline")
    plain = second_allocation_faults("")
    assert plain > PAGES // 2 and kept < PAGES // 10, (plain, kept)


def test_values_do_not_depend_on_where_memory_lives():
    """A zeroed tensor is zero in reused memory too (the block freed before it held ones)."""
    first = torch.ones(BLOCK // 4)
    del first
    assert torch.count_nonzero(torch.zeros(BLOCK // 4)) == 0
