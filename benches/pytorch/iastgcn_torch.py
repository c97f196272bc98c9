"""IASTGCN in PyTorch, written from docs/model.md (the network contract), for the
side-by-side benchmark (`make bench-compare`) and as an interop check: it loads the
engine's safetensors checkpoints (names, shapes and layouts of docs/model.md "Parameter
names") and must give the engine's outputs.

Covers the four IASTGCN variants (iastgcn, iastgcn-a, iastgcn-t, iastgcn-s). Written
the way a PyTorch user would write it: every step on the whole tensor (the engine's
last block computes steps 4-7 at the last time step only, see docs/model.md "Note (the
device schedule)"), the temporal convolutions as `conv1d`, the contractions as
`einsum`/`matmul`. Dropout is PyTorch's own (its mask differs from the engine's hash,
which only matters for training, never for the outputs compared).
"""

import json

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

VARIANTS = ("iastgcn", "iastgcn-a", "iastgcn-t", "iastgcn-s")


def graph_basis(graph, variant, scale, chebyshev_order):
    """The `[terms, N, N]` basis that theta combines (docs/model.md "Graph"), in f64."""
    n = len(graph["nodes"])
    a = np.zeros((n, n))
    for i, j in graph["edges"]:
        a[i, j] = a[j, i] = 1.0
    deg = a.sum(1)
    inv_sqrt = np.where(deg > 0, 1.0 / np.sqrt(np.maximum(deg, 1e-300)), 0.0)
    lap = np.diag((deg > 0).astype(float)) - inv_sqrt[:, None] * a * inv_sqrt[None, :]
    lam, u = np.linalg.eigh(lap)
    if variant == "iastgcn-s":
        scaled = 2.0 * lap / lam[-1] - np.eye(n)
        terms = [np.eye(n), scaled]
        while len(terms) < chebyshev_order:
            terms.append(2.0 * scaled @ terms[-1] - terms[-2])
        return np.stack(terms[:chebyshev_order])
    psi = u @ np.diag(np.exp(-scale * lam)) @ u.T
    psi_inv = u @ np.diag(np.exp(scale * lam)) @ u.T
    return np.stack([np.outer(psi[:, k], psi_inv[k, :]) for k in range(n)])


class Block(nn.Module):
    """One ST block (docs/model.md "One ST block", steps 1-7)."""

    def __init__(self, cfg, c_in, dilation):
        super().__init__()
        n, t, c, k = cfg["nodes"], cfg["window"], cfg["channels"], cfg["kernel"]
        v = cfg["variant"]
        self.attention = v != "iastgcn-a"
        self.gated = v != "iastgcn-t"
        self.dilation = dilation
        self.eps = cfg["eps"]
        self.p = cfg["dropout"]
        z = lambda *s: nn.Parameter(torch.zeros(*s))  # noqa: E731
        if self.attention:
            self.U1, self.U2, self.U3 = z(n), z(c_in, n), z(c_in)
            self.be, self.Ve = z(t, t), z(t, t)
            self.W1, self.W2, self.W3 = z(t), z(c_in, t), z(c_in)
            self.bs, self.Vs = z(n, n), z(n, n)
        terms = cfg["chebyshev_order"] if v == "iastgcn-s" else n
        self.theta, self.W = z(terms), z(c_in, c)
        self.filter_weight, self.filter_bias = z(c, c, k), z(c)
        if self.gated:
            self.gate_weight, self.gate_bias = z(c, c, k), z(c)
        self.res_weight, self.res_bias = z(c, c_in), z(c)
        self.ln_gamma, self.ln_beta = z(c), z(c)

    def causal_conv(self, zz, weight, bias):
        """Step 4's convolution: weight[o, c, k] multiplies z[t - d*k] (k is the lag)."""
        b, n, c, t = zz.shape
        d = self.dilation
        k = weight.shape[2]
        x = F.pad(zz.reshape(b * n, c, t), ((k - 1) * d, 0))
        y = F.conv1d(x, weight.flip(-1), bias, dilation=d)
        return y.reshape(b, n, -1, t)

    def forward(self, x, basis):
        if self.attention:
            # 1. temporal attention (eq. 35-37); softmax over the first T index
            lhs = torch.einsum("bnct,n->btc", x, self.U1) @ self.U2  # [B,T,N]
            rhs = torch.einsum("c,bnct->bnt", self.U3, x)  # [B,N,T]
            e = self.Ve @ torch.sigmoid(lhs @ rhs + self.be)  # [B,T,T]
            e = torch.softmax(e, dim=1)
            xt = x + torch.matmul(x, e.unsqueeze(1))  # X·(E' + I)
            # 2. spatial attention (eq. 32-34); softmax over j
            lhs = torch.einsum("bnct,t->bnc", xt, self.W1) @ self.W2  # [B,N,T]
            rhs = torch.einsum("c,bmct->btm", self.W3, xt)  # [B,T,N]
            s = self.Vs @ torch.sigmoid(lhs @ rhs + self.bs)  # [B,N,N]
            s = torch.softmax(s, dim=2)
            xs = xt + torch.einsum("bij,bjct->bict", s, xt)
        else:
            xs = x
        # 3. graph wavelet (or Chebyshev) convolution (eq. 29)
        psi = torch.einsum("k,kij->ij", self.theta, basis)
        mixed = torch.einsum("ij,bjct->bict", psi, xs)
        zz = torch.relu(torch.einsum("bict,co->biot", mixed, self.W))
        # 4. gated dilated causal convolution (eq. 30-31)
        f = self.causal_conv(zz, self.filter_weight, self.filter_bias)
        if self.gated:
            h = torch.tanh(f) * torch.sigmoid(self.causal_conv(zz, self.gate_weight, self.gate_bias))
        else:
            h = torch.relu(f)
        # 5. residual 1x1 convolution, 6. LayerNorm over C, 7. dropout
        r = torch.einsum("oc,bnct->bnot", self.res_weight, x) + self.res_bias[:, None]
        a = torch.relu(h + r)
        mu = a.mean(2, keepdim=True)
        var = a.var(2, unbiased=False, keepdim=True)
        y = (a - mu) / torch.sqrt(var + self.eps) * self.ln_gamma[:, None] + self.ln_beta[:, None]
        return F.dropout(y, self.p, self.training)


class IASTGCN(nn.Module):
    """The network of docs/model.md: L blocks and the head on the last step."""

    def __init__(self, cfg, graph):
        super().__init__()
        if cfg["variant"] not in VARIANTS:
            raise ValueError(f"variant {cfg['variant']!r}: this model covers {VARIANTS}")
        self.cfg = cfg
        dilations = [1 if cfg["variant"] == "iastgcn-t" else 2**l for l in range(cfg["blocks"])]
        c_ins = [cfg["features"]] + [cfg["channels"]] * (cfg["blocks"] - 1)
        self.blocks = nn.ModuleList(Block(cfg, ci, d) for ci, d in zip(c_ins, dilations))
        self.head_weight = nn.Parameter(torch.zeros(cfg["outputs"], cfg["nodes"] * cfg["channels"]))
        self.head_bias = nn.Parameter(torch.zeros(cfg["outputs"]))
        basis = graph_basis(graph, cfg["variant"], cfg["scale"], cfg["chebyshev_order"])
        self.register_buffer("basis", torch.tensor(basis, dtype=torch.float32))

    def forward(self, x):
        for block in self.blocks:
            x = block(x, self.basis)
        h = x[:, :, :, -1].reshape(x.shape[0], -1)
        return h @ self.head_weight.T + self.head_bias

    def checkpoint_names(self):
        """Parameter name in this module -> tensor name in an engine checkpoint."""
        names = {"head_weight": "head.weight", "head_bias": "head.bias"}
        rename = {
            "filter_weight": "tcn.filter.weight",
            "filter_bias": "tcn.filter.bias",
            "gate_weight": "tcn.gate.weight",
            "gate_bias": "tcn.gate.bias",
            "res_weight": "res.weight",
            "res_bias": "res.bias",
            "ln_gamma": "ln.gamma",
            "ln_beta": "ln.beta",
            "theta": "gwc.theta",
            "W": "gwc.W",
        }
        for l, block in enumerate(self.blocks):
            for name, _ in block.named_parameters():
                if name in rename:
                    ck = rename[name]
                elif name.startswith("U") or name in ("be", "Ve"):
                    ck = f"tat.{name}"
                else:
                    ck = f"sat.{name}"
                names[f"blocks.{l}.{name}"] = f"blocks.{l}.{ck}"
        return names


def load_checkpoint(path):
    """An IASTGCN with the weights of an engine checkpoint (safetensors), in eval mode."""
    from safetensors import safe_open

    with safe_open(path, framework="pt") as f:
        meta = f.metadata()
        if meta.get("format") != "iastgcn-checkpoint/1":
            raise ValueError(f"{path}: format {meta.get('format')!r}, expected iastgcn-checkpoint/1")
        cfg = json.loads(meta["config"])
        model = IASTGCN(cfg, json.loads(meta["graph"]))
        names = model.checkpoint_names()
        present = set(f.keys())
        expected = set(names.values())
        if present != expected:
            raise ValueError(
                f"{path}: tensors differ from the {cfg['variant']} contract: "
                f"missing {sorted(expected - present)}, extra {sorted(present - expected)}"
            )
        with torch.no_grad():
            for name, p in model.named_parameters():
                t = f.get_tensor(names[name])
                if tuple(t.shape) != tuple(p.shape):
                    raise ValueError(f"{path}: {names[name]} is {list(t.shape)}, expected {list(p.shape)}")
                p.copy_(t)
    return model.eval()
