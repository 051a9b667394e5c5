"""How a training process is set up: one thread (the budget of one core), and an allocator that keeps freed
memory for the next update instead of returning it to the system."""

from __future__ import annotations

import torch


def hold_freed_memory() -> bool:
    """Let glibc's allocator keep the memory an update frees, instead of handing it back to the kernel.

    An update allocates and frees dozens of tensors of 0.1-7 MB. By default glibc maps a block above its mmap
    threshold freshly from the kernel and unmaps it when freed, and trims the heap's top as soon as 128 KB are free
    there, so every new tensor page-faults its memory in again: ~1.7 million faults per 1,000 episodes of a
    ``paper`` stack, and its update ran ~1.2x slower, alone or beside a second ``paper`` process (``make bench``
    section 4; a probe beside a ``tuned`` process measured 1.5x). Blocks up to 32 MB now
    come from the heap, which keeps up to 512 MB free and grows 64 MB at a time. The arithmetic is untouched.
    → whether the allocator took the settings (False where it is not glibc's)."""
    import ctypes

    try:
        mallopt = ctypes.CDLL("libc.so.6").mallopt
    except (OSError, AttributeError):
        return False
    m_trim_threshold, m_top_pad, m_mmap_threshold = -1, -2, -3  # <malloc.h>
    settings = ((m_mmap_threshold, 32 << 20), (m_trim_threshold, 512 << 20), (m_top_pad, 64 << 20))
    return all(mallopt(option, value) == 1 for option, value in settings)


def training_process() -> None:
    """Settings of a process that trains: one thread (one process per core is faster than threads for these
    small matrices) and an allocator that keeps freed memory (``hold_freed_memory``). Called by the entry points:
    the CLI, the pipeline's training processes, the tuning trials and the benchmarks."""
    torch.set_num_threads(1)
    hold_freed_memory()
