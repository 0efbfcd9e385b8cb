"""Diagnosis figures: the candidates' predicted drops with their p-values; the discovery's
error falling step by step."""

from __future__ import annotations

import numpy as np

from ..pipeline.figures import _plt, _save


def plot_diagnosis(ds, out):
    plt = _plt()
    splits = [v for v in ds.data_vars if v.startswith("share_")]
    fig, axes = plt.subplots(1, 1 + len(splits), figsize=(7 + 3.2 * len(splits), 3.5), squeeze=False)
    ax = axes[0, 0]
    for a, v in zip(axes[0, 1:], splits):
        dim = ds[v].dims[0]
        a.bar(range(ds.sizes[dim]), 100 * ds[v].values, color="tab:blue")
        a.set_xticks(range(ds.sizes[dim]), ds[dim].values, rotation=20, fontsize=8)
        a.set(ylabel="share of Phi_vol (%)", title=f"misfit by {dim}")
    y = np.arange(ds.sizes["effect"])
    ax.barh(y, 100 * ds.predicted_drop.values, color=["tab:green" if e == ds.attrs["recommended"] else "0.6"
                                                       for e in ds.effect.values])
    for yi, p in zip(y, ds.p_value.values):
        ax.text(0.5, yi, f"p = {p:.2g}", va="center", fontsize=8)
    ax.set_yticks(y, ds.effect.values)
    ax.invert_yaxis()
    ax.set(xlabel="predicted drop of Phi (% of Phi_vol)", title=f"recommended: {ds.attrs['recommended']}")
    fig.tight_layout()
    return _save(fig, out)


def plot_discovery(ds, out):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 3.8))
    x = ds.step.values
    labels = ["base " + str(ds.law.values[0])] + [f"+ {a}" for a in ds.added.values[1:]]
    ax.plot(x, ds.phi_vol.values, "o-", label="Phi_vol")
    ax.plot(x, ds.phi_ind.values, "s--", label="Phi_ind")
    ax.set_xticks(x, labels, rotation=15)
    ax.set(yscale="log", ylabel="misfit (dimensionless, common noise levels)", title="discovery")
    ax.legend()
    fig.tight_layout()
    return _save(fig, out)
