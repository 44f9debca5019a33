"""Retrieval for loop closure on synthetic descriptors: the revisits found, no pair between frames that share nothing."""

import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.geometry.retrieval import revisit_pairs, train_vocabulary, vlad

N_LANDMARKS = 800
SIGHT = 6.0  # a frame sees the landmarks within this distance of where it stands


def _landmarks(rng):
    """Landmarks along a 100-long set: a position each and a SIFT-like descriptor (non-negative, 128 bins)."""
    return rng.uniform(0.0, 100.0, N_LANDMARKS), rng.gamma(0.6, 40.0, (N_LANDMARKS, 128))


def _frames(rng, positions, landmarks):
    """Each frame's descriptors: the landmarks in sight, 80 % of them detected, each with noise; and which."""
    where, descriptors = landmarks
    frames, seen = [], []
    for position in positions:
        visible = np.flatnonzero((np.abs(where - position) <= SIGHT) & (rng.random(N_LANDMARKS) < 0.8))
        noisy = descriptors[visible] + rng.normal(0.0, 8.0, (len(visible), 128))
        frames.append(np.clip(noisy, 0, 255).astype(np.uint8))
        seen.append(set(visible.tolist()))
    return frames, seen


def _retrieve(frames, times, seed=0):
    vocabulary = train_vocabulary(np.concatenate(frames), 32, seed)
    vectors = np.stack([vlad(frame, vocabulary) for frame in frames])
    return revisit_pairs(vectors, times, min_gap=11)


def test_a_shot_out_and_back_finds_its_revisits_and_nothing_between_unrelated_frames():
    """60 frames walking 0 -> 70 -> 0 (keyframes every third frame): the way back's keyframes pair with the way
    out's at the same place; every pair found shares most of its landmarks; run twice, the same pairs."""
    rng = np.random.default_rng(7)
    landmarks = _landmarks(rng)
    times = np.arange(0, 60, 3)
    positions = 70.0 * (1.0 - np.abs(times / 59.0 * 2.0 - 1.0))  # out, then back the same way
    frames, seen = _frames(rng, positions, landmarks)
    pairs = _retrieve(frames, times)
    assert len(pairs) >= 4, pairs
    for i, j, _ in pairs:
        assert abs(positions[i] - positions[j]) < SIGHT, (times[i], times[j], positions[i], positions[j])
        assert len(seen[i] & seen[j]) >= 0.5 * min(len(seen[i]), len(seen[j]))
    assert any(times[i] <= 6 and times[j] >= 53 for i, j, _ in pairs), pairs  # the end back at the start
    assert pairs == _retrieve(frames, times)


def test_a_shot_that_never_comes_back_gives_no_pair():
    """A one-way walk 0 -> 95: frames further apart than the window share no landmark, and no pair is found."""
    rng = np.random.default_rng(8)
    landmarks = _landmarks(rng)
    times = np.arange(0, 60, 3)
    frames, _ = _frames(rng, 95.0 * times / 59.0, landmarks)
    assert _retrieve(frames, times) == []


def test_the_vocabulary_is_seeded_and_vlad_is_a_unit_vector():
    rng = np.random.default_rng(9)
    descriptors = rng.gamma(0.6, 40.0, (200, 128))
    words = train_vocabulary(descriptors, 16, seed=3)
    np.testing.assert_array_equal(words, train_vocabulary(descriptors, 16, seed=3))
    vector = vlad(descriptors[:80], words)
    assert vector.shape == (16 * 128,) and abs(np.linalg.norm(vector) - 1.0) < 1e-6
    assert float(vector @ vlad(descriptors[:80], words)) == pytest.approx(1.0)
    with pytest.raises(CamcalError, match="needs at least as many descriptors"):
        train_vocabulary(descriptors[:10], 16)
