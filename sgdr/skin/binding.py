"""Inverse-distance-weighted binding of Gaussians to anchors (Eq. 14 of the seed paper).

Each Gaussian centre μ_g is bound once, at rest, to its n_b nearest anchors a (cKDTree) with
weights w_ga = d_ga^-p_b / Σ_a' d_ga'^-p_b (distances floored at `min_distance`). Forms:
- `official`:      μ_g = Σ_a w_ga x_a                      (frame 0 is the IDW average, not μ_g)
- `displacement`:  μ_g = μ_g^rest + Σ_a w_ga (x_a - x_a^rest)  (exact at rest)
`apply` is a Dr.Jit sum loop over the n_b anchors (gathers only), differentiable w.r.t. the
anchor positions through a `dr.CustomOp` (`_WeightedSum`) whose backward is gathers only too:
Dr.Jit's own adjoint of the forward's gathers would scatter-add the M n_b weighted Gaussian
adjoints into the N_A anchors in an order set by the thread schedule, so anchor gradients
would change with the thread count. Instead each anchor sums, in a fixed order, over the
(Gaussian, slot) pairs bound to it: the transpose of the binding, built once in NumPy
(`anchor_transpose`: pairs sorted by anchor, then by Gaussian; CSR offsets per anchor).
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import numpy as np
from scipy.spatial import cKDTree

from sgdr.anchors.sampling import AnchorInputError
from sgdr.backend import ad
from sgdr.registry import Registry

# name -> form(binding, anchor_x) -> Gaussian centres Array3f [M] (see the module docstring)
BINDING_FORMS = Registry("IDW binding form", "anchors.binding", AnchorInputError)


def anchor_transpose(anchor_index: np.ndarray, n_anchors: int) -> tuple[np.ndarray, np.ndarray]:
    """The binding's transpose: (pair_offset [N_A + 1], pair [M * n_b]) uint32 such that the
    flat slots s = g * n_b + b bound to anchor a are pair[pair_offset[a]:pair_offset[a + 1]],
    in increasing s (Gaussian order). anchor_index: [M * n_b] (or [M, n_b]) anchor of each slot."""
    idx = np.asarray(anchor_index, dtype=np.int64).reshape(-1)
    pair = np.argsort(idx, kind="stable")
    offset = np.zeros(n_anchors + 1, dtype=np.int64)
    np.cumsum(np.bincount(idx, minlength=n_anchors), out=offset[1:])
    return offset.astype(np.uint32), pair.astype(np.uint32)


def idw_weights(rest_centres: np.ndarray, anchors: np.ndarray, n_b: int, p_b: float, min_distance: float = 1e-8):
    """(index [M, n_b] int64, weights [M, n_b] float64 summing to 1), nearest anchor first."""
    dist, idx = cKDTree(anchors).query(rest_centres, k=n_b)
    dist, idx = dist.reshape(-1, n_b), idx.reshape(-1, n_b)
    w = np.maximum(dist, min_distance) ** (-float(p_b))
    return idx, w / w.sum(axis=1, keepdims=True)


@dataclass
class IDWBinding:
    """Fixed binding of M Gaussians to N_A anchors (Eq. 14)."""

    anchor_index: object  # UInt32 [M * n_b], anchors of Gaussian g at g*n_b .. g*n_b+n_b-1
    weight: object  # Float [M * n_b], normalised IDW weights
    rest_centres: object  # Array3f [M] Gaussian centres at rest, world
    anchors_rest: object  # Array3f [N_A] anchor positions at rest, world
    n_b: int
    form: str  # "official" | "displacement"
    pair_offset: object  # UInt32 [N_A + 1], anchor a's slots are pair[pair_offset[a]:pair_offset[a+1]]
    pair: object  # UInt32 [M * n_b] flat slots g * n_b + b sorted by anchor, then by g

    @staticmethod
    def build(
        rest_centres: np.ndarray,
        anchors: np.ndarray,
        n_b: int,
        p_b: float,
        form: str = "official",
        min_distance: float = 1e-8,
    ) -> IDWBinding:
        t = ad()
        rest_centres = np.asarray(rest_centres, dtype=np.float64)
        anchors = np.asarray(anchors, dtype=np.float64)
        for name, a in (("rest_centres", rest_centres), ("anchors", anchors)):
            if a.ndim != 2 or a.shape[1] != 3:
                raise AnchorInputError(f"IDWBinding.build: {name} must have shape [N, 3], got {a.shape}")
            if not np.all(np.isfinite(a)):
                raise AnchorInputError(f"IDWBinding.build: {name} contain NaN/inf")
        if not 1 <= n_b <= anchors.shape[0]:
            raise AnchorInputError(f"anchors.n_b={n_b} must be in [1, N_A={anchors.shape[0]}]")
        BINDING_FORMS.get_named(form)
        idx, w = idw_weights(rest_centres, anchors, n_b, p_b, min_distance)
        pair_offset, pair = anchor_transpose(idx, anchors.shape[0])
        return IDWBinding(
            anchor_index=t.UInt32(idx.reshape(-1).astype(np.uint32)),
            weight=t.Float(w.reshape(-1).astype(np.float32)),
            rest_centres=t.Array3f(*rest_centres.T.astype(np.float32)),
            anchors_rest=t.Array3f(*anchors.T.astype(np.float32)),
            n_b=int(n_b),
            form=form,
            pair_offset=t.UInt32(pair_offset),
            pair=t.UInt32(pair),
        )

    @property
    def count(self) -> int:
        return dr.width(self.rest_centres)

    def apply(self, anchor_x) -> object:
        """Gaussian centres Array3f [M] from anchor positions Array3f [N_A] (differentiable)."""
        if dr.width(anchor_x) != dr.width(self.anchors_rest):
            raise AnchorInputError(
                f"IDWBinding.apply: anchor_x has {dr.width(anchor_x)} entries, binding has N_A={dr.width(self.anchors_rest)}"
            )
        return BINDING_FORMS.get_named(self.form)(self, anchor_x)

    def weighted_sum(self, values) -> object:
        """Σ_a w_ga values_a for every Gaussian g: Array3f [M] from Array3f [N_A] (a sum loop
        over the n_b bound anchors, gathers only; differentiable w.r.t. values, with a
        gather-only backward that does not depend on the thread count)."""
        return dr.custom(_WeightedSum, values, self)

    def gather_sum(self, values) -> object:
        """The forward of `weighted_sum` (no custom op): Array3f [M] from Array3f [N_A]."""
        t = ad()
        m, n_b = self.count, self.n_b
        base = dr.arange(t.UInt32, m) * n_b

        def body(b, acc):
            s = base + b
            a = dr.gather(t.UInt32, self.anchor_index, s)
            w = dr.gather(t.Float, self.weight, s)
            return b + 1, acc + w * dr.gather(t.Array3f, values, a)

        _, acc = dr.while_loop(
            state=(dr.zeros(t.UInt32, m), dr.zeros(t.Array3f, m)),
            cond=lambda b, acc: b < n_b,
            body=body,
            labels=("b", "acc"),
            label="idw_apply",
            max_iterations=-1,
        )
        return acc

    def transpose_sum(self, grad_centres) -> object:
        """The adjoint of `weighted_sum`: ḡ_a = Σ_{g bound to a} w_ga δ_g for every anchor, an
        Array3f [N_A] from Array3f [M]; a per-anchor sum loop over the binding's transpose
        (gathers only, a fixed summation order)."""
        t = ad()
        n_a = dr.width(self.anchors_rest)
        a = dr.arange(t.UInt32, n_a)
        end = dr.gather(t.UInt32, self.pair_offset, a + 1)

        def body(q, acc):
            s = dr.gather(t.UInt32, self.pair, q)
            w = dr.gather(t.Float, self.weight, s)
            return q + 1, acc + w * dr.gather(t.Array3f, grad_centres, s // self.n_b)

        _, acc = dr.while_loop(
            state=(dr.gather(t.UInt32, self.pair_offset, a), dr.zeros(t.Array3f, n_a)),
            cond=lambda q, acc: q < end,
            body=body,
            labels=("q", "acc"),
            label="idw_apply_adjoint",
            max_iterations=-1,
        )
        return acc


class _WeightedSum(dr.CustomOp):
    """`IDWBinding.weighted_sum` as a custom op. Input (AD): values Array3f [N_A]; output:
    Array3f [M]. Backward: `transpose_sum` (a per-anchor loop; deterministic). Forward mode:
    the weighted sum of the input tangents."""

    def eval(self, values, binding: IDWBinding):
        self.binding = binding
        return binding.gather_sum(values)

    def forward(self):
        self.set_grad_out(self.binding.gather_sum(self.grad_in("values")))

    def backward(self):
        self.set_grad_in("values", self.binding.transpose_sum(self.grad_out()))

    def name(self):
        return "IDWWeightedSum"


@BINDING_FORMS.register("official")
def bind_official(binding: IDWBinding, anchor_x):
    """μ_g = Σ_a w_ga x_a (the official weighted anchor positions)."""
    return binding.weighted_sum(anchor_x)


@BINDING_FORMS.register("displacement")
def bind_displacement(binding: IDWBinding, anchor_x):
    """μ_g = μ_g^rest + Σ_a w_ga (x_a - x_a^rest) (exact at rest)."""
    return binding.rest_centres + binding.weighted_sum(anchor_x - binding.anchors_rest)
