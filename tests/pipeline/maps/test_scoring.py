"""The numpy scoring kernels of pipeline.maps.scoring."""

import numpy as np

from pipeline.maps.scoring import chunked_scores, logsumexp


def test_chunked_scores_equal_one_product_of_the_upcast_features():
    rng = np.random.default_rng(1)
    f16 = rng.standard_normal((1001, 16)).astype(np.float16)
    text = rng.standard_normal((3, 16)).astype(np.float32)
    want = f16.astype(np.float32) @ text.T
    for rows in (100, 1001, 4096):  # a short last chunk, one exact chunk, one chunk larger than the map
        got = chunked_scores(f16, text, chunk_rows=rows)
        assert got.dtype == np.float32 and got.shape == (1001, 3)
        np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-6)
    assert chunked_scores(f16[:0], text).shape == (0, 3)


def test_logsumexp_is_stable_and_handles_all_minus_infinity():
    x = np.array([[1000.0, 1000.0], [-np.inf, -np.inf], [0.0, np.log(3.0)]])
    np.testing.assert_allclose(logsumexp(x, axis=1), [1000.0 + np.log(2.0), -np.inf, np.log(4.0)])
