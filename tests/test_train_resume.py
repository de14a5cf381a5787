"""The shuffle-buffer sampler resumes where it stopped: same batches as an uninterrupted iteration."""

from __future__ import annotations

import types

import numpy as np

from nue.train.dataset import BufferSampler


def test_buffer_sampler_state_round_trip_gives_the_same_batches():
    data = types.SimpleNamespace(n_episodes=7, lengths=np.random.default_rng(5).integers(1, 20, 7))
    full = BufferSampler(data, 4, np.random.default_rng(1), buffer_episodes=3)
    reference = [next(full) for _ in range(60)]
    cut = BufferSampler(data, 4, np.random.default_rng(1), buffer_episodes=3)
    head = [next(cut) for _ in range(13)]  # stop inside a buffer
    saved, rng_state = cut.state_dict(), cut.rng.bit_generator.state
    rng = np.random.default_rng(99)  # a fresh process: another generator, restored below
    rng.bit_generator.state = rng_state
    resumed = BufferSampler(data, 4, rng, buffer_episodes=3)
    resumed.load_state_dict(saved)
    tail = [next(resumed) for _ in range(47)]
    for (ea, sa), (eb, sb) in zip(reference, head + tail):
        assert np.array_equal(ea, eb) and np.array_equal(sa, sb)
    fresh = BufferSampler(data, 4, np.random.default_rng(1), buffer_episodes=3)
    fresh.rng.bit_generator.state = rng_state  # the generator alone is not enough
    assert any(not np.array_equal(next(fresh)[0], e) for e, _ in reference[13:20])
