"""The synthetic swept-sine noise model does what its docstring states."""

import numpy as np
import pytest

from samii import notebook as nb
from samii.identify import ModelStructure, SweptSineNoise, synthesize
from samii.identify.synthetic import coherence_model, random_error


def test_random_error_is_bendat_piersol():
    # table 9.6: eps = sqrt(1 - g) / (sqrt(g) sqrt(2 n)); g = 0.99, n = 3 -> 0.04103
    assert random_error(np.array([0.99]), 3)[0] == pytest.approx(np.sqrt(0.01 / (0.99 * 6)))
    assert random_error(np.array([1.0]), 3)[0] == 0.0


def test_noise_statistics_match_the_model():
    f = np.linspace(1.0, 2.0, 20000)
    h = np.ones(f.size, complex)
    h[::2] = 10 ** (-50 / 20)  # half the points 50 dB below the peak: coherence < 1
    noise = SweptSineNoise(n_averages=3, dynamic_range_db=60.0, min_coherence=0.5)
    fr = synthesize(f, {"act": h}, noise=noise, rng=np.random.default_rng(0))
    g = coherence_model(h, noise)
    low = g < 0.99
    eps = random_error(g[low], 3)[0]
    err = np.log(fr.act[low] / h[low])
    assert np.std(20 * np.log10(np.e) * err.real) == pytest.approx(8.6859 * eps, rel=0.03)
    assert np.std(np.degrees(err.imag)) == pytest.approx(57.296 * eps, rel=0.03)
    assert abs(np.mean(err.real)) < 3 * eps / np.sqrt(low.sum())  # unbiased in log magnitude


def test_coherence_falls_at_the_antiresonance():
    st = ModelStructure.notebook_3mode()
    f = np.geomspace(0.1, 40, 400)
    fr = synthesize(f, {c: st.response(nb.EQ9_4, f, c) for c in ("act", "base")}, noise=SweptSineNoise(), rng=np.random.default_rng(1))
    i_notch = np.argmin(np.abs(f - nb.EQ9_4["wz"] / (2 * np.pi)))
    assert fr.act_coh[i_notch] < fr.act_coh[np.argmin(np.abs(f - 1.0))]
    assert fr.base_coh.min() == pytest.approx(0.5)  # the clip, reached by the s^4 channel below 1 Hz
    assert "3 averages" in fr.metadata["noise"]


def test_noise_free_and_bad_arguments():
    f = np.array([1.0, 2.0])
    fr = synthesize(f, {"act": np.array([1 + 1j, 2.0])}, noise=None)
    np.testing.assert_array_equal(fr.act_coh, 1.0)
    with pytest.raises(ValueError, match="Generator"):
        synthesize(f, {"act": np.ones(2)}, noise=SweptSineNoise())
    with pytest.raises(ValueError, match="n_averages"):
        SweptSineNoise(n_averages=0)
