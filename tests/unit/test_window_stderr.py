"""Standard errors of windowed fits: clustered by window, never exactly 0."""

from __future__ import annotations

import numpy as np
import torch

from identification.trajectory.windowed_fit import NormalEquations, window_stderr

T = torch.linspace(0.0, 1.0, 30, dtype=torch.float64)


def _fit(y: torch.Tensor) -> tuple[float, NormalEquations, torch.Tensor, float]:
    """Least squares of ``y_bm = a_b + θ t_m`` (a_b local, θ global) and its normal equations."""
    B, m = y.shape
    tc = T - T.mean()
    theta = float((y * tc).sum() / (B * (tc * tc).sum()))
    a = (y - theta * T).mean(1)
    r = a[:, None] + theta * T - y  # model - data, as the fits' residuals
    ones = torch.ones(B, m, dtype=torch.float64)
    ne = NormalEquations(
        H_ll=torch.full((B, 1, 1), float(m), dtype=torch.float64),
        H_lg=(ones * T).sum(1).reshape(B, 1, 1),
        g_l=r.sum(1, keepdim=True),
        H_gg=torch.tensor([[B * float((T * T).sum())]], dtype=torch.float64),
        g_g=(r * T).sum().reshape(1),
        sse=float((r * r).sum()),
        m=B * m,
        g_gb=(r * T).sum(1, keepdim=True),
    )
    S = torch.tensor([[B * float((tc * tc).sum())]], dtype=torch.float64)
    return theta, ne, S, float((r * r).sum()) / (B * m - B - 1)


def test_sandwich_covers_window_correlated_errors() -> None:
    rng = np.random.default_rng(0)
    hit_sandwich, hit_gauss = [], []
    for _ in range(300):
        B = 20
        # each window shares a random slope error: residuals correlated along the window
        slope = rng.normal(0, 0.5, size=(B, 1))
        y = torch.as_tensor(rng.normal(0, 1, (B, 1)) + (1.0 + slope) * T.numpy()
                            + rng.normal(0, 0.1, (B, len(T))))  # fmt: skip
        theta, ne, S, sigma2 = _fit(y)
        se = float(window_stderr(ne, S, sigma2)[0])
        gauss = float(np.sqrt(sigma2 / float(S[0, 0])))
        hit_sandwich.append(abs(theta - 1.0) <= 2 * se)
        hit_gauss.append(abs(theta - 1.0) <= 2 * gauss)
    assert np.mean(hit_sandwich) >= 0.9
    assert np.mean(hit_gauss) < 0.5  # independent-residual errors are far too small here


def test_independent_errors_keep_the_gauss_newton_value() -> None:
    rng = np.random.default_rng(1)
    y = torch.as_tensor(rng.normal(0, 1, (40, 1)) + T.numpy() + rng.normal(0, 0.1, (40, len(T))))
    _, ne, S, sigma2 = _fit(y)
    se = float(window_stderr(ne, S, sigma2)[0])
    assert se >= np.sqrt(sigma2 / float(S[0, 0]))
    assert se < 2 * np.sqrt(sigma2 / float(S[0, 0]))


def test_a_direction_the_data_does_not_see_is_infinite_not_zero() -> None:
    rng = np.random.default_rng(2)
    y = torch.as_tensor(rng.normal(0, 1, (10, 1)) + T.numpy() + rng.normal(0, 0.1, (10, len(T))))
    _, ne, S, sigma2 = _fit(y)
    # a second global coordinate no residual depends on
    S2 = torch.zeros(2, 2, dtype=torch.float64)
    S2[0, 0] = S[0, 0]
    ne2 = NormalEquations(ne.H_ll, torch.cat([ne.H_lg, torch.zeros_like(ne.H_lg)], -1), ne.g_l,
                          torch.diag(torch.stack([ne.H_gg[0, 0], torch.tensor(0.0).double()])),
                          torch.cat([ne.g_g, torch.zeros(1).double()]), ne.sse, ne.m,
                          torch.cat([ne.g_gb, torch.zeros_like(ne.g_gb)], -1))  # fmt: skip
    se = window_stderr(ne2, S2, sigma2)
    assert np.isfinite(se[0]) and se[0] > 0
    assert se[1] == np.inf


def test_coordinates_on_scales_ten_orders_apart_are_both_seen() -> None:
    # a log-stiffness barely seen beside an effect coefficient in its own units:
    # curvatures 1e-6 and 1e8, correlated 0.5; nothing here is collinear
    c = 0.5 * np.sqrt(1e8 * 1e-6)
    S = torch.tensor([[1e8, c], [c, 1e-6]], dtype=torch.float64)
    ne = NormalEquations(
        H_ll=torch.ones(1, 1, 1, dtype=torch.float64),
        H_lg=torch.zeros(1, 1, 2, dtype=torch.float64),
        g_l=torch.zeros(1, 1, dtype=torch.float64),
        H_gg=S,
        g_g=torch.zeros(2, dtype=torch.float64),
        sse=1.0,
        m=10,
        g_gb=torch.zeros(1, 2, dtype=torch.float64),
    )
    se = window_stderr(ne, S, 1.0)
    exact = np.sqrt(np.diag(np.linalg.inv(S.numpy())))
    np.testing.assert_allclose(se, exact, rtol=1e-9)
