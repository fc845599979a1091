"""The compiled (numba) products of the stitching's least squares (`solve`): A x and Aᵀ r, with
the bits of the numpy expressions they replace (the same operations in the same order: numpy's
pairwise summation of each unknown's terms included). No bpy. Nothing compiles until `get()`
(`core.compiled`).

numpy's `add.reduceat` sums a run of n terms as the first plus the pairwise sum of the other
n − 1: fewer than 8 one by one from −0.0; up to PAIRWISE_BLOCK with 8 running sums combined as
((s0 + s1) + (s2 + s3)) + ((s4 + s5) + (s6 + s7)), then the remainder one by one; a longer run
is split in two (recursively), which `apply_at` leaves to numpy (`long` marks those runs).
"""

from __future__ import annotations

from ... import compiled

#: The longest run of terms (after its first) numpy's pairwise summation sums as one block.
PAIRWISE_BLOCK = 128


def apply_a(taps, coeff, x, out):
    """`out (C, R)` (zeros, x's dtype) += x[:, taps[k]] · coeff[k] for k = 0 … 7 in turn: the
    read difference of each row. `taps (8, R)` int, `coeff (8, R)` float32, `x (C, N)`."""
    channels, rows = out.shape
    for c in range(channels):
        for r in range(rows):
            acc = out[c, r]
            for k in range(taps.shape[0]):
                acc += x[c, taps[k, r]] * coeff[k, r]
            out[c, r] = acc


def apply_at(entry_row, entry_coeff, starts, owner, r, out, long, negative_zero):
    """Aᵀ r: `out[:, owner[i]]` (C, N) = the sum of run i of r[:, entry_row[e]] · entry_coeff[e]
    (the runs start at `starts`, the last ends at the end), as numpy's `add.reduceat` sums it.
    Runs of more than PAIRWISE_BLOCK + 1 terms are left alone and marked in `long` (bool, per
    run). `negative_zero`: a 1-element array of −0.0 in out's dtype (the short sums' start)."""
    runs, entries = starts.shape[0], entry_row.shape[0]
    for i in range(runs):
        a = starts[i]
        b = starts[i + 1] if i + 1 < runs else entries
        rest = b - a - 1
        if rest > PAIRWISE_BLOCK:
            long[i] = True
            continue
        t = owner[i]
        for c in range(r.shape[0]):
            first = r[c, entry_row[a]] * entry_coeff[a]
            if rest == 0:
                out[c, t] = first
                continue
            e = a + 1
            if rest < 8:
                total = negative_zero[0]
                for j in range(rest):
                    total += r[c, entry_row[e + j]] * entry_coeff[e + j]
            else:
                s0 = r[c, entry_row[e]] * entry_coeff[e]
                s1 = r[c, entry_row[e + 1]] * entry_coeff[e + 1]
                s2 = r[c, entry_row[e + 2]] * entry_coeff[e + 2]
                s3 = r[c, entry_row[e + 3]] * entry_coeff[e + 3]
                s4 = r[c, entry_row[e + 4]] * entry_coeff[e + 4]
                s5 = r[c, entry_row[e + 5]] * entry_coeff[e + 5]
                s6 = r[c, entry_row[e + 6]] * entry_coeff[e + 6]
                s7 = r[c, entry_row[e + 7]] * entry_coeff[e + 7]
                j = 8
                while j < rest - rest % 8:
                    s0 += r[c, entry_row[e + j]] * entry_coeff[e + j]
                    s1 += r[c, entry_row[e + j + 1]] * entry_coeff[e + j + 1]
                    s2 += r[c, entry_row[e + j + 2]] * entry_coeff[e + j + 2]
                    s3 += r[c, entry_row[e + j + 3]] * entry_coeff[e + j + 3]
                    s4 += r[c, entry_row[e + j + 4]] * entry_coeff[e + j + 4]
                    s5 += r[c, entry_row[e + j + 5]] * entry_coeff[e + j + 5]
                    s6 += r[c, entry_row[e + j + 6]] * entry_coeff[e + j + 6]
                    s7 += r[c, entry_row[e + j + 7]] * entry_coeff[e + j + 7]
                    j += 8
                total = ((s0 + s1) + (s2 + s3)) + ((s4 + s5) + (s6 + s7))
                while j < rest:
                    total += r[c, entry_row[e + j]] * entry_coeff[e + j]
                    j += 1
            out[c, t] = first + total


KERNELS = compiled.KernelSet(__name__, kernels=("apply_a", "apply_at"))
get = KERNELS.get
