"""Band-limited white noise and the seeded disturbance streams."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy import signal
from sixdof_helper import sixdof_config

from dcsms_ros.core import compiledsos, fastsim
from dcsms_ros.core.config import load_config
from dcsms_ros.core.disturbance import (
    BLOCK,
    CHUNK,
    BandNoise,
    Disturbances,
    band_sos,
    noise_gain,
)
from dcsms_ros.core.sosfilter import sosfilt
from dcsms_ros.errors import ConfigError

FS = 2000.0


@pytest.mark.parametrize("band", [(0.5, 100.0), (5.0, 50.0), (0.0, 200.0), (10.0, 1000.0)])
def test_band_noise_rms(band):
    """Output RMS equals the requested RMS within 5 % on every channel."""
    rms = np.array([2e-6, 5e-6, 1.0])
    x = BandNoise(rms, band, FS, 3, np.random.default_rng(1)).block(200_000)
    assert_allclose(np.sqrt(np.mean(x**2, axis=0)), rms, rtol=0.05)


def test_band_noise_psd_flat_in_band():
    """The PSD is flat at rms^2/(noise gain) * 2/fs inside the band and falls outside it."""
    bn = BandNoise(1.0, (0.5, 100.0), FS, 1, np.random.default_rng(2))
    x = bn.block(400_000)[:, 0]
    f, p = signal.welch(x, fs=FS, nperseg=4096)
    level = 2.0 / FS / noise_gain(band_sos((0.5, 100.0), FS))
    for lo, hi in [(3.0, 10.0), (10.0, 30.0), (30.0, 60.0)]:
        sel = (f >= lo) & (f < hi)
        assert_allclose(np.mean(p[sel]), level, rtol=0.05)
    assert np.mean(p[(f > 400) & (f < 600)]) < 0.01 * level


def test_noise_gain_matches_white_variance():
    """Unfiltered noise has unit gain; a band gain equals the impulse-response energy."""
    assert noise_gain(None) == 1.0
    sos = band_sos((5.0, 50.0), FS)
    _, h = signal.sosfreqz(sos, worN=2**16, fs=FS)
    assert_allclose(noise_gain(sos), np.mean(np.abs(h) ** 2), rtol=1e-3)


def test_band_noise_block_independent():
    """next() and block(n) in any mix give the same deterministic sequence."""
    a = BandNoise(1.0, (0.5, 100.0), FS, 2, np.random.default_rng(3)).block(3000)
    b = BandNoise(1.0, (0.5, 100.0), FS, 2, np.random.default_rng(3))
    parts = [b.block(7), np.array([b.next() for _ in range(1500)]), b.block(1493)]
    assert_allclose(np.vstack(parts), a, rtol=0, atol=0)


def _whole_blocks(rms, band, channels, seed, n):
    """The noise of ``BandNoise(..., warm=False)`` built independently: each block of white
    noise drawn whole and filtered whole by scipy, the state carried, then scaled."""
    rng = np.random.default_rng(seed)
    sos = band_sos(band, FS)
    zi = np.zeros((sos.shape[0], 2, channels))
    out = []
    for _ in range(-(-n // BLOCK)):
        y, zi = signal.sosfilt(sos, rng.standard_normal((BLOCK, channels)), axis=0, zi=zi)
        out.append(y * (rms / np.sqrt(noise_gain(sos))))
    return np.vstack(out)[:n]


@pytest.mark.parametrize("run", [sosfilt, compiledsos.sosfilt, pytest.param(
    fastsim.sosfilt, marks=pytest.mark.skipif(not fastsim.available(), reason="no numba"))],
    ids=["python", "scipy", "numba"])
def test_band_noise_split_keeps_the_bits(run):
    """Served row by row (the nodes), in odd blocks, or whole (the engine), with the Python
    or the compiled block filter: the same bits as whole blocks filtered by scipy."""
    n = 3 * BLOCK + 77
    want = _whole_blocks(2e-6, (0.5, 100.0), 3, 11, n)
    rows = BandNoise(2e-6, (0.5, 100.0), FS, 3, np.random.default_rng(11), warm=False,
                     block_filter=run)
    got_rows = np.array([rows.next() for _ in range(n)])
    odd = BandNoise(2e-6, (0.5, 100.0), FS, 3, np.random.default_rng(11), warm=False,
                    block_filter=run)
    got_odd = np.vstack([odd.block(m) for m in (5, BLOCK - 5, 1, 700, BLOCK + 323 + 77 + 1,
                                                BLOCK - 1)])
    assert_allclose(got_rows, want, rtol=0, atol=0)
    assert_allclose(got_odd[:n], want, rtol=0, atol=0)


def test_band_noise_next_filters_a_chunk_at_a_time():
    """A sample served by next() filters at most CHUNK rows: a block's filtering is spread
    over its samples, not paid in the one step that starts it (the real-time plant's)."""
    sizes: list[int] = []

    def counting(sos, x, zi):
        sizes.append(x.shape[0])
        return sosfilt(sos, x, zi)

    bn = BandNoise(1.0, (0.5, 100.0), FS, 2, np.random.default_rng(5), block_filter=counting)
    warm = len(sizes)
    assert warm >= 1 and set(sizes) == {BLOCK}  # the warm-up filters whole blocks
    served = [bn.next().copy() for _ in range(3 * BLOCK)]
    assert max(sizes[warm:]) == CHUNK
    # the warm-up's last block is served first; every row after it was filtered once
    assert sum(sizes[warm:]) == 2 * BLOCK
    assert not bn.next().flags.writeable  # rows are views of the block
    assert np.isfinite(served).all()


class _CountingRng:
    """A generator that records how many rows each normal draw asks for."""

    def __init__(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)
        self.rows: list[int] = []

    def standard_normal(self, size):
        self.rows.append(size[0])
        return self.rng.standard_normal(size)


def test_band_noise_next_draws_a_chunk_at_a_time():
    """A sample served by next() draws at most CHUNK rows of white noise too: a whole block's
    draw in the sample that starts it made that sample ~128 us long (the real-time plant's);
    the rows are the whole-block draw's all the same (test above)."""
    rng = _CountingRng(5)
    bn = BandNoise(1.0, (0.5, 100.0), FS, 2, rng)
    warm = len(rng.rows)
    for _ in range(3 * BLOCK):
        bn.next()
    assert max(rng.rows[warm:]) == CHUNK
    assert sum(rng.rows[warm:]) == 2 * BLOCK  # the warm-up's last block is served first


def test_band_noise_rejects_empty_band():
    """An upper edge not above the lower edge is a configuration error."""
    with pytest.raises(ConfigError):
        BandNoise(1.0, (50.0, 5.0), FS, 1, np.random.default_rng(0))


@pytest.mark.parametrize("cfg", [load_config(), sixdof_config()], ids=["1dof", "6dof"])
def test_disturbances_deterministic_and_shaped(cfg):
    """Same seed -> same streams; another seed differs; rotations and moments are zero."""
    def run(seed):
        d = Disturbances(cfg, seed)
        out = [d.next() for _ in range(2000)]
        return np.array([g for g, _ in out]), np.array([w for _, w in out])

    g1, w1 = run(5)
    g2, w2 = run(5)
    g3, _ = run(6)
    dof, n = cfg.plant.dof, cfg.plant.num_stages
    assert g1.shape == (2000, dof) and w1.shape == (2000, n, dof)
    assert_allclose(g1, g2, rtol=0, atol=0)
    assert_allclose(w1, w2, rtol=0, atol=0)
    assert not np.allclose(g1, g3)
    if dof == 6:
        assert np.all(g1[:, 3:] == 0.0) and np.all(w1[:, :, 3:] == 0.0)
    z = 0 if dof == 1 else 2
    assert abs(np.corrcoef(g1[:, z], w1[:, 0, z])[0, 1]) < 0.2


def test_disturbance_levels_1dof():
    """1dof ground RMS is the z value and table forces have force_rms_n."""
    cfg = load_config()
    d = Disturbances(cfg)
    out = [d.next() for _ in range(60_000)]
    g = np.array([o[0] for o in out])
    w = np.array([o[1] for o in out])
    assert_allclose(np.sqrt(np.mean(g**2)), cfg.disturbance.ground_rms_mps[2], rtol=0.1)
    assert_allclose(np.sqrt(np.mean(w**2, axis=0)).ravel(), cfg.disturbance.force_rms_n, rtol=0.1)


def test_ground_replay_loops_with_flag():
    """A recorded ground replaces the noise and loops at its end with ground_exhausted set."""
    cfg = load_config()
    rec = np.arange(5.0)[:, None] * 1e-6
    d = Disturbances(cfg, 1, ground=rec)
    got = [d.next()[0][0] for _ in range(5)]
    assert_allclose(got, rec[:, 0]) and not d.ground_exhausted
    with pytest.warns(RuntimeWarning):
        assert d.next()[0][0] == rec[0, 0]
    assert d.ground_exhausted
    with pytest.raises(ConfigError):
        Disturbances(cfg, 1, ground=np.zeros((5, 6)))
