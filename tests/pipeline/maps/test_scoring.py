"""The numpy scoring kernels of pipeline.maps.scoring."""

import numpy as np

from pipeline.maps.scoring import chunked_scores, logsumexp, upcast


def test_upcast_is_exact_for_every_half_float():
    every = np.arange(1 << 16, dtype=np.uint16).view(np.float16)
    got = upcast(every.reshape(256, 256))
    assert got.dtype == np.float32 and got.shape == (256, 256)
    assert np.array_equal(got.ravel(), every.astype(np.float32), equal_nan=True)
    assert np.signbit(upcast(np.array([-0.0], np.float16)))[0]
    big = np.random.default_rng(0).standard_normal((4100, 512)).astype(np.float16)  # more than one 2M block
    assert np.array_equal(upcast(big), big.astype(np.float32)) and upcast(big[:, ::2]).shape == (4100, 256)


def test_chunked_scores_equal_one_product_of_the_upcast_features():
    rng = np.random.default_rng(1)
    f16 = rng.standard_normal((1001, 16)).astype(np.float16)
    text = rng.standard_normal((3, 16)).astype(np.float32)
    np.testing.assert_allclose(chunked_scores(f16, text, chunk_rows=100), f16.astype(np.float32) @ text.T, rtol=1e-6)


def test_logsumexp_is_stable_and_handles_all_minus_infinity():
    x = np.array([[1000.0, 1000.0], [-np.inf, -np.inf], [0.0, np.log(3.0)]])
    np.testing.assert_allclose(logsumexp(x, axis=1), [1000.0 + np.log(2.0), -np.inf, np.log(4.0)])
