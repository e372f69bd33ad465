"""The sum-of-sinusoids reference: the paper's eq. (21) in closed form, its derivatives, and the
sampling's bits against the formula written out term by term."""

from __future__ import annotations

import math

import numpy as np

from hydroarm.model.task.references import SinusoidReference, paper_reference


def _written_out(ref: SinusoidReference, t):
    """Each term of (q, v, a) written out, in the order of the docstring's formula."""
    wt = ref.omega * np.asarray(t, dtype=float)[..., None, None]
    c, s = np.cos(wt), np.sin(wt)
    q = ref.offset + np.sum(ref.cos_amp * c + ref.sin_amp * s, axis=-1)
    v = np.sum(ref.omega * (-ref.cos_amp * s + ref.sin_amp * c), axis=-1)
    a = np.sum(-(ref.omega**2) * (ref.cos_amp * c + ref.sin_amp * s), axis=-1)
    return q, v, a


def test_paper_reference_is_eq_21_with_its_derivatives():
    ref = paper_reference()
    for t in (0.0, 0.37, 2.5, 9.99):
        q, v, a = ref.sample(t)
        c1, s1, c2, s2 = math.cos(t), math.sin(t), math.cos(2 * t), math.sin(2 * t)
        np.testing.assert_allclose(q, [3 * c1 + 2 * s2, s2, 2 * c1, 2 * c2, s1, 3 * c1 + 2 * s2], atol=1e-14)
        np.testing.assert_allclose(v, [-3 * s1 + 4 * c2, 2 * c2, -2 * s1, -4 * s2, c1, -3 * s1 + 4 * c2], atol=1e-14)
        np.testing.assert_allclose(a, [-3 * c1 - 8 * s2, -4 * s2, -2 * c1, -8 * c2, -s1, -3 * c1 - 8 * s2], atol=1e-14)


def test_sampling_gives_the_written_out_formula_bit_for_bit():
    """Scalar times (Python and NumPy floats, ints) and arrays of times, on the paper's reference and
    random ones with more terms: the kept factors and the shared sum change no bit."""
    rng = np.random.default_rng(0)
    refs = [paper_reference()]
    for n, m in ((7, 3), (5, 12)):
        omega = rng.uniform(0.1, 5.0, (n, m))
        refs.append(SinusoidReference(rng.normal(size=n), rng.normal(size=(n, m)), rng.normal(size=(n, m)), omega))
    for ref in refs:
        times = [
            *rng.uniform(-5.0, 50.0, 200),
            0.0,
            np.float64(1.23),
            3,
            rng.uniform(0, 10, 50),
            rng.uniform(0, 10, (4, 5)),
        ]
        for t in times:
            for got, expected in zip(ref.sample(t), _written_out(ref, t), strict=True):
                assert got.shape == expected.shape
                assert np.array_equal(got, expected)
