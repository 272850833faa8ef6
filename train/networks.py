"""Actor and critic networks over the pursuer observation (pursuit_mj.obs_spec).

`reference` (DESIGN.md section 6): one encoder per entity kind (self, teammate, evader, the
range readings, and with belief features the remembered evaders and the search goal), each
a linear layer with tanh; teammates and evaders are mean-pooled over the entities whose
visibility flag is 1 (hidden ones count for nothing, none visible
gives zeros; caught evaders count for nothing either), so one network serves any number of
teammates and evaders. The pooled codes
are concatenated and fused by tanh layers (hidden widths), then a head. `mlp`: the flat
observation through tanh layers (fixed team size). Every weight is orthogonal, every bias 0.

All networks take obs (..., obs_dim) float32 tensors and keep the leading shape.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from pursuit_mj.obs_spec import ObsSpec

from .config import NetConfig


TINY = 1e-30  # |x| below this is set to 0: denormal floats slow CPU matrix products a hundredfold


def flush_tiny(x: torch.Tensor) -> torch.Tensor:
    """x with denormal-range values zeroed (a drone at rest reports velocities like 1e-40)."""
    return torch.where(x.abs() < TINY, torch.zeros((), dtype=x.dtype), x)


class _SigmoidTanh(torch.autograd.Function):
    """tanh(x) as 2 sigmoid(2x) - 1, differentiated as tanh: d/dx = 1 - y^2 from the output y."""

    @staticmethod
    def forward(ctx, x: torch.Tensor) -> torch.Tensor:
        y = torch.sigmoid(x * 2.0).mul_(2.0).sub_(1.0)
        ctx.save_for_backward(y)
        return y

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> torch.Tensor:
        (y,) = ctx.saved_tensors
        return torch.ops.aten.tanh_backward(grad, y)


SIGMOID_TANH_MIN_SIZE = 4096  # elements; below this torch.tanh is as fast


def tanh(x: torch.Tensor) -> torch.Tensor:
    """tanh, within 2e-7 of torch.tanh. On large tensors it is computed through sigmoid: when
    this was tuned, torch's tanh kernel was several times slower than its sigmoid (70 vs
    16 us on 256 x 128), and the update's minibatches made tanh 15 % of its time. It can be the
    other way round (8.9 vs 26 us on a later day: docs/experiments.md, section 7); the
    formula stays, because changing it changes every trained network's numbers in their last
    bits, and with them the episode-by-episode replay of every documented table."""
    if x.numel() < SIGMOID_TANH_MIN_SIZE:
        return torch.tanh(x)
    if x.requires_grad and torch.is_grad_enabled():
        return _SigmoidTanh.apply(x)
    return torch.sigmoid(x * 2.0).mul_(2.0).sub_(1.0)


class Tanh(nn.Module):
    """nn.Tanh computed by `tanh` above."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return tanh(x)


def init_linear(layer: nn.Linear, gain: float = math.sqrt(2.0)) -> nn.Linear:
    """Orthogonal weight (gain), zero bias. The QR decomposition behind orthogonal_ rounds
    differently on one thread than on two, so it always runs on one: the same seed gives the
    same weights whatever thread count the process was left at (a second run in one process
    otherwise started 1e-8 away from the first and trained differently)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        nn.init.orthogonal_(layer.weight, gain)
    finally:
        torch.set_num_threads(threads)
    nn.init.zeros_(layer.bias)
    return layer


def tanh_mlp(sizes: list[int]) -> nn.Sequential:
    """Linear+tanh per consecutive pair of `sizes` (orthogonal init, gain sqrt(2))."""
    layers: list[nn.Module] = []
    for a, b in zip(sizes[:-1], sizes[1:]):
        layers += [init_linear(nn.Linear(a, b)), Tanh()]
    return nn.Sequential(*layers)


def masked_mean(codes: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean of codes (..., K, C) over the K entities where mask (..., K) is 1; zeros where none is."""
    weight = mask.unsqueeze(-1)
    total = (codes * weight).sum(dim=-2)
    count = weight.sum(dim=-2).clamp_min(1.0)
    return total / count


LOG_SQRT_2PI = math.log(math.sqrt(2.0 * math.pi))


def gaussian_log_prob(mean: torch.Tensor, std: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """Per-dimension log density of x under N(mean, std^2); all (..., A), std = log_std.exp().

    The same operations as torch.distributions.Normal(mean, std).log_prob(x), so values and
    gradients are bit-identical, without that class's per-call argument checks.
    """
    return -((x - mean) ** 2) / (2 * std**2) - std.log() - LOG_SQRT_2PI


def gaussian_entropy(std: torch.Tensor) -> torch.Tensor:
    """Per-dimension entropy (..., A) of N(., std^2), as Normal(., std).entropy() computes it."""
    return 0.5 + 0.5 * math.log(2 * math.pi) + torch.log(std)


class EntityEncoder(nn.Module):
    """Encodes every entity of one kind with shared weights and pools the visible ones.

    Works for any entity count, including zero (then the output is zeros).
    """

    def __init__(self, width: int, out: int, mask_feature: int | None, exclude_feature: int | None = None):
        super().__init__()
        self.width = width
        self.mask_feature = mask_feature
        self.exclude_feature = exclude_feature  # entities with this flag at 1 are left out of the pool
        self.layer = init_linear(nn.Linear(width, out))

    def forward(self, entities: torch.Tensor) -> torch.Tensor:
        """entities (..., K, width) -> (..., out)."""
        codes = tanh(self.layer(entities))
        if self.mask_feature is None and entities.shape[-2] == 1:
            return codes.squeeze(-2)  # one always-present entity (self, rays): its code, bit for bit
        if self.mask_feature is None:
            mask = torch.ones(entities.shape[:-1], dtype=entities.dtype, device=entities.device)
        else:
            mask = (entities[..., self.mask_feature] > 0.5).to(entities.dtype)
        if self.exclude_feature is not None:
            mask = mask * (entities[..., self.exclude_feature] <= 0.5).to(entities.dtype)
        return masked_mean(codes, mask)


class PooledTrunk(nn.Module):
    """Observation -> fused features through per-entity encoders with masked mean pooling."""

    ANY_TEAM = True  # pooled encoders: weights that fit one team size fit every other
    GROUPS = ("self", "teammates", "evaders", "rays")
    SHAPE_KEYS = ("kind", "encoder_width", "hidden", "use_rays")  # the net.* keys its weights depend on
    BELIEF_GROUPS = ("memory", "goal")  # pooled like evaders / encoded like self (pursuit_mj.belief)

    def __init__(self, spec: ObsSpec, cfg: NetConfig):
        super().__init__()
        self.use_rays = cfg.use_rays and spec.n_rays > 0
        groups = [g for g in self.GROUPS if g != "rays" or self.use_rays]
        if spec.has_belief:
            groups += list(self.BELIEF_GROUPS)
        self.encoders = nn.ModuleDict()
        for name in groups:
            g = spec.group(name)
            width = g.width if name != "rays" else spec.n_rays
            # a caught evader stays visible where it stopped; pooling it with the free ones would
            # blur where the chase is, so only free evaders count (one evader: no change)
            exclude = g.features.index("captured") if "captured" in g.features else None
            self.encoders[name] = EntityEncoder(width, cfg.encoder_width, g.mask_feature, exclude)
        self.fuse = tanh_mlp([cfg.encoder_width * len(groups), *cfg.hidden])
        self.out_dim = cfg.hidden[-1]

    def forward(self, obs: torch.Tensor, spec: ObsSpec) -> torch.Tensor:
        """obs (..., spec.dim) float32 -> features (..., out_dim)."""
        parts = []
        for name, enc in self.encoders.items():
            g = spec.group(name)
            parts.append(enc(obs[..., g.start : g.stop].reshape(obs.shape[:-1] + (g.count, g.width))))
        return self.fuse(torch.cat(parts, dim=-1))


class FlatTrunk(nn.Module):
    """Observation -> features through a plain tanh MLP (team size fixed at construction)."""

    ANY_TEAM = False  # every teammate and evader slot has weights of its own, by its place in the vector
    SHAPE_KEYS = ("kind", "hidden")  # the net.* keys its weights depend on (no encoders: encoder_width, use_rays unused)

    def __init__(self, spec: ObsSpec, cfg: NetConfig):
        super().__init__()
        self.obs_dim = spec.dim
        self.fuse = tanh_mlp([spec.dim, *cfg.hidden])
        self.out_dim = cfg.hidden[-1]

    def forward(self, obs: torch.Tensor, spec: ObsSpec) -> torch.Tensor:
        """obs (..., spec.dim) float32 -> features (..., out_dim)."""
        if spec.dim != self.obs_dim:
            raise ValueError(f"net.kind mlp was built for obs_dim {self.obs_dim}, got {spec.dim}: use net.kind reference to change team sizes")
        return self.fuse(obs)


#: net.kind -> trunk class; a new network is one class here and its name in train/config.py NET_KINDS.
#: A trunk is built as cls(spec, cfg: NetConfig), has `out_dim`, and its forward(obs, spec) maps obs
#: (..., spec.dim) float32 to features (..., out_dim); Actor and Critic put their heads on it
#: (docs/training.md, "Network").
#: Its SHAPE_KEYS name the net.* keys its weights depend on (--init-from compares those; all of
#: train/run_checks.py ACTOR_SHAPE_KEYS when it has none).
TRUNKS: dict[str, type[nn.Module]] = {"reference": PooledTrunk, "mlp": FlatTrunk}


def team_mismatch(kind: str, trained: dict, spec: ObsSpec) -> str | None:
    """Why a network of net.kind `kind` trained on observations `trained` (ObsSpec.to_dict) cannot
    read those of `spec`, or None. A trunk without ANY_TEAM reads each slot by its place, so it
    takes only the team it was trained with: for another one its weights do not fit, or (8
    pursuers and 1 evader fill as many slots as 1 and 6) fit and read evaders as teammates."""
    if getattr(TRUNKS.get(kind), "ANY_TEAM", True):
        return None
    was, now = (trained["n_pursuers"], trained["n_evaders"]), (spec.n_pursuers, spec.n_evaders)
    if was == now:
        return None

    def team(n: int, m: int) -> str:
        return f"{n} pursuer{'s' if n != 1 else ''} and {m} evader{'s' if m != 1 else ''}"

    return (f"net.kind {kind} reads the team it was trained with, {team(*was)}, and this environment has "
            f"{team(*now)}: run it with that team, or train a network for any team size (net.kind reference, "
            f"whose pooled encoders take any number of teammates and evaders)")


def registered_from_outside(kind: str, spawns: str) -> str | None:
    """Why a run whose `spawns` (the run.* settings that start a child process, e.g.
    'run.overlap') builds networks in a spawned process cannot train net.kind `kind`, or None.
    A kind that some other code (a script) put into TRUNKS after this module was imported, or a
    class it put in place of the module's own, is unknown to a spawned process, which imports
    this module afresh and does not run that code."""
    if kind not in TRUNKS or TRUNKS[kind] is MODULE_TRUNKS.get(kind):
        return None
    return (f"net.kind {kind!r} was registered in train/networks.py TRUNKS from outside that module (a script): "
            f"{spawns} builds the networks again in a spawned process, which imports train/networks.py afresh "
            f"and does not run the script; add the class to train/networks.py itself and its name to "
            f"train/config.py NET_KINDS (docs/training.md, 'Adding a network'), or train in this process: "
            f"--set run.split_update=false with run.overlap false")


def trunk_class(kind: str) -> type[nn.Module]:
    """The trunk class of net.kind `kind` (a key of TRUNKS), or ValueError naming the kind and the
    known ones: a kind without a class here must not train, nor be loaded as, some other network."""
    try:
        return TRUNKS[kind]
    except KeyError:
        raise ValueError(f"net.kind {kind!r}: no such network in train/networks.py TRUNKS "
                         f"(known: {', '.join(TRUNKS)})") from None


def make_trunk(spec: ObsSpec, cfg: NetConfig) -> nn.Module:
    """The trunk net.kind names (trunk_class)."""
    return trunk_class(cfg.kind)(spec, cfg)


class Actor(nn.Module):
    """Gaussian policy: mean = tanh(head(trunk(obs))) in [-1, 1]^2, log std a free parameter."""

    ACTION_DIM = 2

    def __init__(self, spec: ObsSpec, cfg: NetConfig):
        super().__init__()
        self.trunk = make_trunk(spec, cfg)
        self.head = init_linear(nn.Linear(self.trunk.out_dim, self.ACTION_DIM), 0.01)
        self.log_std = nn.Parameter(torch.full((self.ACTION_DIM,), float(cfg.init_log_std)))

    def forward(self, obs: torch.Tensor, spec: ObsSpec) -> tuple[torch.Tensor, torch.Tensor]:
        """(mean (..., 2), log_std (..., 2)) for obs (..., spec.dim): the mean action in [-1, 1]
        (fraction of pursuer_speed, world x/y) and the log of its std (in the same fractions)."""
        mean = tanh(self.head(self.trunk(obs, spec)))
        return mean, self.log_std.expand_as(mean)

    def distribution(self, obs: torch.Tensor, spec: ObsSpec) -> torch.distributions.Normal:
        """The action distribution (batch shape (..., 2), as `forward`) for obs (..., spec.dim)."""
        mean, log_std = self(obs, spec)
        return torch.distributions.Normal(mean, log_std.exp())


class Critic(nn.Module):
    """Per-agent value V(obs) (...,) in reward units for obs (..., spec.dim), with the same trunk
    family as the actor, separate weights."""

    def __init__(self, spec: ObsSpec, cfg: NetConfig):
        super().__init__()
        self.trunk = make_trunk(spec, cfg)
        self.head = init_linear(nn.Linear(self.trunk.out_dim, 1), 1.0)

    def forward(self, obs: torch.Tensor, spec: ObsSpec) -> torch.Tensor:
        """Values (...,) in reward units of obs (..., spec.dim)."""
        return self.head(self.trunk(obs, spec)).squeeze(-1)


class CentralCritic(nn.Module):
    """MAPPO critic: value of each pursuer from the global state and that pursuer's observation.

    state (..., state_dim) and obs (..., obs_dim) -> (...,) in normalised value units. Appending
    the pursuer's own observation makes the value agent-specific (Yu et al. 2022).
    """

    def __init__(self, spec: ObsSpec, state_dim: int, cfg: NetConfig):
        super().__init__()
        self.state_dim = state_dim
        self.obs_dim = spec.dim
        self.body = tanh_mlp([state_dim + spec.dim, *cfg.critic_hidden])
        self.head = init_linear(nn.Linear(cfg.critic_hidden[-1], 1), 1.0)

    def forward(self, state: torch.Tensor, obs: torch.Tensor) -> torch.Tensor:
        """Values (...,) in normalised units of state (..., state_dim) and obs (..., obs_dim)."""
        return self.head(self.body(torch.cat([state, obs], dim=-1))).squeeze(-1)


#: TRUNKS as this module defines it: what a spawned process (critic, rollout worker) knows (registered_from_outside)
MODULE_TRUNKS: dict[str, type[nn.Module]] = dict(TRUNKS)
