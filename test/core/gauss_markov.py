"""A first-order Gauss-Markov sequence, the gyro wander the wander tests draw."""

import math

import numpy as np


def gauss_markov(rng, n, dt_s, sigma, tau_s):
    """Return n samples, dt_s apart, of a stationary wander of sigma and correlation tau_s."""
    phi = math.exp(-dt_s / tau_s)
    c = np.empty(n)
    c[0] = rng.normal(0.0, sigma)
    steps = rng.normal(0.0, sigma * math.sqrt(1.0 - phi * phi), n)
    for k in range(1, n):
        c[k] = phi * c[k - 1] + steps[k]
    return c
