"""Candidate poses, filters, view scoring, argmax selection and -OPT refinement (METHOD.md 12-14).

Pose vectors are ``[qx, qy, qz, qw, x, y, z]`` (nvf.cameras). The model is anything following the
``SceneModel`` contract (``.aabb``, ``.density(x) -> sigma``, ``.render(origins, dirs,
heads, train, generator, sampler)``); the scorer is a ``nvf.uncertainty.ViewScorer`` (per pixel) or a
``WholeViewScorer`` (FisherRF, METHOD 17: a step's ``StepScorer`` after ``prepare_scorer``; argmax only).
``scorer=None`` is the Random method (METHOD 12).

Randomness (PROTOCOL.md 3): every draw uses a generator from a ``GeneratorFactory``, a callable that
maps a purpose string to a fresh generator seeded from ``(run seed, step, purpose)``; see
``nvf.seeding.generator_factory``. Purposes used here: ``"candidates"`` (pose draws and the M29 jitter),
``"random_pick"`` (Random) and ``"opt_rays/<iteration>"`` (-OPT ray subsets).
"""

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch
from jaxtyping import Bool, Float, Int
from torch import Tensor, nn

from nvf.cameras import (
    Intrinsics,
    camera_directions,
    matrix_to_pose,
    pose_to_matrix,
    rays_from_camera_dirs,
    se3_update,
)
from nvf.config import OptConfig, PlannerConfig
from nvf.observations import Observations
from nvf.seeding import GeneratorFactory
from nvf.uncertainty import StepScorer, ViewScorer, WholeViewScorer
from nvf.visibility import segment_transmittance

# (origin [3], points [n,3]) -> [n] True where the segment from origin to the point is free (M29, los_source=mesh)
LineOfSight = Callable[[Float[Tensor, "3"], Float[Tensor, "n 3"]], Bool[Tensor, " n"]]

_QUAT_EPS = 1e-9  # METHOD 13 step 2


class NoCandidatesError(RuntimeError):
    """Every candidate pose was rejected by a filter (METHOD 13: an error of the step)."""


# ----------------------------------------------------------------------------------------------
# Candidates and filters (METHOD 13, M28, M29)
# ----------------------------------------------------------------------------------------------


def sample_poses(n: int, camera_box: Float[Tensor, "2 3"], generator: torch.Generator) -> Float[Tensor, "n 7"]:
    """``n`` random poses: positions uniform in ``camera_box`` (rows min, max), orientations a
    normalised 4-D standard normal read as ``[qx,qy,qz,qw]``; no look-at (METHOD 13, D10).

    Positions are drawn first, then quaternions, on the generator's device; the result lives on
    ``camera_box``'s device.
    """
    gdev = generator.device
    lo, hi = camera_box[0].to(gdev), camera_box[1].to(gdev)
    positions = lo + (hi - lo) * torch.rand(n, 3, generator=generator, device=gdev)
    quats = torch.randn(n, 4, generator=generator, device=gdev)
    quats = quats / torch.linalg.norm(quats, dim=-1, keepdim=True)
    return torch.cat([quats, positions], dim=-1).to(camera_box.device)


def valid_pose_mask(poses: Float[Tensor, "n 7"]) -> Bool[Tensor, " n"]:
    """Quaternion filter (METHOD 13 step 2): quaternion norm > 1e-9 and no NaN in the pose."""
    return (torch.linalg.norm(poses[:, :4], dim=-1) > _QUAT_EPS) & ~poses.isnan().any(dim=-1)


@torch.no_grad()
def density_mask(model: nn.Module, positions: Float[Tensor, "n 3"], tau: float) -> Bool[Tensor, " n"]:
    """(M28) Keep a camera centre if ``sigma(x) < tau``; the field returns 0 outside the AABB."""
    sigma = model.density(positions)  # type: ignore[operator]  # a duck-typed nn.Module's attribute
    return sigma < tau


def candidate_poses(
    model: nn.Module,
    cfg: PlannerConfig,
    camera_box: Float[Tensor, "2 3"],
    current_pose: Float[Tensor, "7"] | None,
    tau: float,
    collision_free: bool,
    generator: torch.Generator,
    apply_filters: bool = True,
    line_of_sight: LineOfSight | None = None,
) -> Float[Tensor, "m 7"]:
    """Candidate poses of one planning step (METHOD 13), ``m <= cfg.num_candidates``.

    Base sampler: draw ``floor(cfg.oversample * N)`` poses; collision-free sampler: draw ``3N``.
    Always drop invalid quaternions; with ``apply_filters`` also apply the density filter (M28,
    threshold ``tau``) and, if ``collision_free``, the line-of-sight filter from ``current_pose``'s
    centre (M29: M17's ``segment_transmittance`` with ``cfg.los_samples`` stratified samples jittered
    by ``generator``, keep ``T > cfg.los_threshold``; with ``cfg.los_unobserved_free`` the density reads
    0 in cells no training sample reached, ``model.observed_density``; with ``cfg.los_source == "mesh"``
    the exact segment test ``line_of_sight`` replaces the model, a deviation, docs/DEVIATIONS.md).
    Keep the first ``min(N, count)``. Raises ``NoCandidatesError`` when a filter leaves nothing.
    """
    n = cfg.num_candidates
    drawn = 3 * n if collision_free else math.floor(cfg.oversample * n)
    poses = sample_poses(drawn, camera_box, generator).to(model.aabb.device)  # type: ignore[arg-type]  # a duck-typed nn.Module's attribute
    stages: list[tuple[str, Callable[[Tensor], Tensor]]] = [("quaternion filter", valid_pose_mask)]
    if apply_filters:
        stages.append((f"density filter M28 (tau={tau:g})", lambda p: density_mask(model, p[:, 4:], tau)))
        if collision_free:
            if current_pose is None:
                raise ValueError("the collision-free sampler (M29) needs the current pose")
            origin = current_pose[4:].to(poses)
            if cfg.los_source == "mesh":
                if line_of_sight is None:
                    raise ValueError("planner.los_source=mesh needs the scene mesh's line_of_sight test")
                stages.append(("line-of-sight filter M29 (scene mesh)", lambda p: line_of_sight(origin, p[:, 4:])))
            elif cfg.los_source == "model":
                los_density = model.observed_density if cfg.los_unobserved_free else model.density

                def los(p: Tensor) -> Tensor:
                    trans = segment_transmittance(los_density, origin, p[:, 4:], cfg.los_samples, generator, model.aabb)  # type: ignore[arg-type]  # a duck-typed nn.Module's attribute
                    return trans > cfg.los_threshold

                stages.append((f"line-of-sight filter M29 (T > {cfg.los_threshold:g})", los))
            else:
                raise ValueError(f"planner.los_source={cfg.los_source!r} is not one of model, mesh")
    for name, keep in stages:
        before = poses.shape[0]
        poses = poses[keep(poses)]
        if poses.shape[0] == 0:
            raise NoCandidatesError(f"no candidate poses left: the {name} rejected all {before} of {drawn} drawn poses")
    return poses[:n]


# ----------------------------------------------------------------------------------------------
# Scoring and selection (M16, METHOD 13)
# ----------------------------------------------------------------------------------------------


def _check_finite(scores: Tensor, what: str) -> None:
    bad = (~torch.isfinite(scores)).nonzero().flatten()
    if bad.numel() > 0:
        raise FloatingPointError(f"non-finite view score for {what} {bad.tolist()[:8]} (scorer bug)")


def prepare_scorer(
    scorer: ViewScorer | StepScorer | None,
    model: nn.Module,
    observations: Observations,
    generators: GeneratorFactory,
    chunk_rays: int,
) -> ViewScorer | WholeViewScorer | None:
    """The scorer one planning step uses: ``scorer.prepare(...)`` for a ``StepScorer`` (FisherRF's ``H_D``
    from the step's model and training views, METHOD 17), else ``scorer`` itself."""
    if isinstance(scorer, StepScorer):
        return scorer.prepare(model, observations, generators, chunk_rays)
    return scorer


@torch.no_grad()
def score_poses(
    model: nn.Module,
    scorer: ViewScorer | WholeViewScorer,
    poses: Float[Tensor, "m 7"],
    intrinsics: Intrinsics,
    chunk_rays: int,
) -> Float[Tensor, " m"]:
    """(M16) View reward ``R(p)`` of each pose: mean of ``scorer.pixel_scores`` over the full image; for a
    ``WholeViewScorer``, its ``view_score`` of the full image (METHOD 17).

    Each pose's rays are rendered in row-major chunks of ``chunk_rays`` (use a multiple of the
    scorer's depth chunk, 4096, for ``depth_mode=chunk``) with ``scorer.heads`` and
    ``scorer.sampler``; ``pixel_index`` (row-major id) is always passed. float64; raises
    ``FloatingPointError`` on a non-finite score. ``score_poses_together`` with one scorer.
    """
    return score_poses_together(model, [scorer], poses, intrinsics, chunk_rays)[0]


@torch.no_grad()
def score_poses_together(
    model: nn.Module,
    scorers: list[ViewScorer | WholeViewScorer],
    poses: Float[Tensor, "m 7"],
    intrinsics: Intrinsics,
    chunk_rays: int,
) -> list[Float[Tensor, " m"]]:
    """``score_poses`` of every scorer on the same model: the per-pixel scorers with the same ``sampler`` read
    one render of each chunk, with the union of their heads (a head's values do not depend on which other heads
    are rendered, so each score is bitwise its own render's); a ``WholeViewScorer`` renders for itself."""
    cam_dirs = camera_directions(intrinsics, poses.device)
    num_pixels = cam_dirs.shape[0]
    scores: list[Tensor | None] = [None] * len(scorers)
    for j, scorer in enumerate(scorers):
        if isinstance(scorer, WholeViewScorer):
            rays = (rays_from_camera_dirs(c2w, cam_dirs) for c2w in pose_to_matrix(poses))
            scores[j] = torch.stack([scorer.view_score(model, origins, dirs, chunk_rays) for origins, dirs in rays])
    groups: dict[str, list[int]] = {}
    for j, scorer in enumerate(scorers):
        if not isinstance(scorer, WholeViewScorer):
            groups.setdefault(scorer.sampler, []).append(j)
    for sampler, members in groups.items():
        heads = frozenset().union(*(scorers[j].heads for j in members))  # type: ignore[union-attr]  # ViewScorers only
        sums = torch.zeros(len(members), poses.shape[0], dtype=torch.float64, device=poses.device)
        for i, c2w in enumerate(pose_to_matrix(poses)):
            origins, dirs = rays_from_camera_dirs(c2w, cam_dirs)
            for start in range(0, num_pixels, chunk_rays):
                index = torch.arange(start, min(start + chunk_rays, num_pixels), device=poses.device)
                result = model.render(origins[index], dirs[index], heads=heads, train=False, sampler=sampler)  # type: ignore[operator]  # a duck-typed nn.Module's attribute
                for g, j in enumerate(members):
                    pixel = scorers[j].pixel_scores(result, pixel_index=index)  # type: ignore[union-attr]  # ViewScorers only
                    sums[g, i] += pixel.to(torch.float64).sum()
        for g, j in enumerate(members):
            scores[j] = sums[g] / num_pixels
    done = [found for found in scores if found is not None]
    assert len(done) == len(scorers), "every scorer is a ViewScorer or a WholeViewScorer"
    for found in done:
        _check_finite(found, "pose")
    return done


@dataclass
class ScoreSummary:
    """Statistics of the candidates' view rewards (population std). ``ties_at_max``: how many candidates
    share the maximum exactly; above 1 the argmax is the first of them in draw order (METHOD 13), a pick
    among candidates the score cannot tell apart."""

    count: int
    min: float
    mean: float
    max: float
    std: float
    ties_at_max: int

    @staticmethod
    def of(scores: Float[Tensor, " m"]) -> "ScoreSummary":
        s = scores.to(torch.float64)
        top = s.max()
        return ScoreSummary(
            s.numel(), s.min().item(), s.mean().item(), top.item(), s.std(correction=0).item(), int((s == top).sum())
        )


@dataclass
class OptTrace:
    """What -OPT did (METHOD 14): the top-k candidates and the refined poses, re-scored."""

    original_indices: Int[Tensor, " k"]  # candidate indices of the top-k, best first
    original_scores: Float[Tensor, " k"]  # their full-image scores (re-scored)
    refined_poses: Float[Tensor, "j 7"]  # refined poses without NaN
    refined_from: Int[Tensor, " j"]  # candidate index each refined pose started from
    refined_scores: Float[Tensor, " j"]  # their full-image scores


@dataclass
class Selection:
    """The chosen next view. ``index`` is the candidate it is (or, for -OPT, was refined from)."""

    pose: Float[Tensor, "7"]
    index: int
    score: float | None  # full-image R(p); None for Random
    num_candidates: int
    candidate_scores: ScoreSummary | None  # None for Random
    refined: bool = False  # -OPT: the pose is a refined one
    opt: OptTrace | None = None
    candidates: Float[Tensor, "m 7"] | None = None  # every candidate pose, in draw order
    scores: Float[Tensor, " m"] | None = None  # their full-image R(p); None for Random


def argmax_first(scores: Float[Tensor, " m"]) -> int:
    """Index of the maximum; ties go to the lowest index (METHOD 13)."""
    return int((scores == scores.max()).nonzero()[0, 0])


def random_pick(m: int, generator: torch.Generator) -> int:
    """Random's choice among ``m`` candidates (METHOD 12): one uniform draw from ``generator`` (a step's
    ``generators("random_pick")``)."""
    return int(torch.randint(m, (1,), generator=generator, device=generator.device))


def top_k_first(scores: Float[Tensor, " m"], k: int) -> Int[Tensor, " k2"]:
    """Indices of the ``min(k, m)`` best scores, best first; ties keep the lower index first."""
    return torch.sort(scores, descending=True, stable=True).indices[: min(k, scores.shape[0])]


# ----------------------------------------------------------------------------------------------
# -OPT (METHOD 14, supplement Alg. S2)
# ----------------------------------------------------------------------------------------------


def ray_subset(num_pixels: int, chunk_rays: int, fraction: float, generator: torch.Generator) -> Int[Tensor, " n"]:
    """Sorted row-major pixel ids: a random ``floor(fraction * n)`` of each ``chunk_rays`` chunk
    of ``n`` pixels (METHOD 14; 8,987 of a 300x300 image at 10 %). On the generator's device."""
    parts = []
    for start in range(0, num_pixels, chunk_rays):
        n = min(chunk_rays, num_pixels - start)
        pick = torch.randperm(n, generator=generator, device=generator.device)[: math.floor(fraction * n)]
        parts.append(start + pick.sort().values)
    return torch.cat(parts)


def refine_poses(
    model: nn.Module,
    scorer: ViewScorer,
    poses: Float[Tensor, "k 7"],
    camera_box: Float[Tensor, "2 3"],
    intrinsics: Intrinsics,
    opt: OptConfig,
    generators: GeneratorFactory,
) -> tuple[Float[Tensor, "j 7"], Int[Tensor, " j"]]:
    """-OPT gradient refinement (METHOD 14, Alg. S2) of the ``k`` starting poses.

    One Adam (``opt.lr``) for ``opt.iters`` iterations over all poses. Iteration ``i`` renders,
    per pose, the ``ray_subset`` (``opt.ray_fraction`` of each ``opt.chunk_rays`` chunk) drawn from
    ``generators(f"opt_rays/{i}")``, with rays that depend differentiably on the pose, and minimises
    ``-sum_poses mean_rays pixel_scores``. Gradients reach the field through the sample positions
    and view directions; only the pose parameters are stepped (model ``.grad`` is left untouched).

    Parameterisations (``opt.param``):
    - ``quat_raw``: the raw 7-vectors are the leaf; the rotation uses the un-normalised quaternion;
      after each step quaternions are renormalised and positions clipped to ``camera_box``.
    - ``se3``: 6 parameters per pose, ``xi = [rho, phi]``, applied left-multiplicatively,
      ``c2w = se3_exp(xi) @ c2w_base`` (nvf.cameras.se3_update). After each step the update is
      folded into the base pose (position clipped to ``camera_box``, rotation re-orthonormalised
      through its quaternion) and ``xi`` is reset to 0; Adam's moments carry over.

    A pose that turns NaN is not rendered again. Returns the refined poses without rows containing
    NaN and the input row each came from.
    """
    if opt.param not in ("quat_raw", "se3"):
        raise ValueError(f"unknown -OPT parameterisation {opt.param!r} (quat_raw | se3)")
    box = camera_box.to(poses)
    cam_dirs = camera_directions(intrinsics, poses.device)
    if opt.param == "quat_raw":
        leaf = poses.detach().clone().requires_grad_(True)
    else:
        base = poses.detach().clone()
        leaf = torch.zeros(poses.shape[0], 6, dtype=poses.dtype, device=poses.device, requires_grad=True)
    optimiser = torch.optim.Adam([leaf], lr=opt.lr)

    def c2w_of(i: int) -> Tensor:
        if opt.param == "quat_raw":
            return pose_to_matrix(leaf[i])
        return se3_update(pose_to_matrix(base[i]), leaf[i])

    for iteration in range(opt.iters):
        generator = generators(f"opt_rays/{iteration}")
        grad = torch.zeros_like(leaf)
        state = leaf.detach() if opt.param == "quat_raw" else base
        for i in range(poses.shape[0]):
            index = ray_subset(cam_dirs.shape[0], opt.chunk_rays, opt.ray_fraction, generator).to(poses.device)
            if state[i].isnan().any():
                continue  # diverged: never rendered again, dropped at the end
            with torch.enable_grad():
                origins, dirs = rays_from_camera_dirs(c2w_of(i), cam_dirs[index])
                result = model.render(origins, dirs, heads=scorer.heads, train=False, sampler=scorer.sampler)  # type: ignore[operator]  # a duck-typed nn.Module's attribute
                loss = -scorer.pixel_scores(result, pixel_index=index).mean()
                if loss.requires_grad:
                    (g,) = torch.autograd.grad(loss, [leaf], allow_unused=True)
                    if g is not None:
                        grad += g
        leaf.grad = grad
        optimiser.step()
        with torch.no_grad():
            if opt.param == "quat_raw":
                leaf[:, :4] /= torch.linalg.norm(leaf[:, :4], dim=-1, keepdim=True)
                leaf[:, 4:] = torch.minimum(torch.maximum(leaf[:, 4:], box[0]), box[1])
            else:
                moved = matrix_to_pose(se3_update(pose_to_matrix(base), leaf))
                moved[:, 4:] = torch.minimum(torch.maximum(moved[:, 4:], box[0]), box[1])
                base = moved
                leaf.zero_()
    refined = (leaf if opt.param == "quat_raw" else base).detach()
    keep = ~refined.isnan().any(dim=-1)
    return refined[keep], keep.nonzero().flatten()


# ----------------------------------------------------------------------------------------------
# One planning step
# ----------------------------------------------------------------------------------------------


def select_next_view(
    model: nn.Module,
    scorer: ViewScorer | WholeViewScorer | None,
    cfg: PlannerConfig,
    camera_box: Float[Tensor, "2 3"],
    current_pose: Float[Tensor, "7"] | None,
    intrinsics: Intrinsics,
    tau: float,
    collision_free: bool,
    generators: GeneratorFactory,
    line_of_sight: LineOfSight | None = None,
) -> Selection:
    """Choose the next view (METHOD 12-14).

    - ``scorer is None`` (Random, METHOD 12): candidates without the M28/M29 filters unless
      ``cfg.random_filters``; one picked uniformly with ``generators("random_pick")``.
    - ``cfg.name == "argmax"``: score every candidate on the full planning image (``intrinsics``,
      chunks of ``cfg.score_chunk_rays``) and take the argmax, ties to the lowest index.
    - ``cfg.name == "opt"``: refine the top ``cfg.opt.top_k`` (``refine_poses``), re-score the
      original top-k followed by the refined poses on the full image and take the argmax (ties to
      the earlier entry, i.e. an original over its refinement). The choice therefore never scores
      below the best starting candidate. No filter re-check after refinement (METHOD 14.4). It needs a
      per-pixel score: a ``WholeViewScorer`` is refused (ValueError).

    ``tau`` and ``collision_free`` are the resolved scene values; ``current_pose`` is the most
    recently observed pose (needed by the collision-free sampler); ``line_of_sight``: the scene mesh's
    segment test, needed when ``cfg.los_source == "mesh"`` (``candidate_poses``).
    """
    if cfg.name == "opt" and scorer is not None and not isinstance(scorer, ViewScorer):
        raise ValueError(f"-OPT refines poses by a per-pixel score; {scorer.name} scores whole views: use argmax")
    filters = scorer is not None or cfg.random_filters
    candidates = candidate_poses(
        model, cfg, camera_box, current_pose, tau, collision_free, generators("candidates"), filters, line_of_sight
    )
    m = candidates.shape[0]
    if scorer is None:
        index = random_pick(m, generators("random_pick"))
        return Selection(candidates[index], index, None, m, None, candidates=candidates)
    if cfg.name not in ("argmax", "opt"):
        raise ValueError(f"unknown planner {cfg.name!r} (argmax | opt; Random is scorer=None)")
    scores = score_poses(model, scorer, candidates, intrinsics, cfg.score_chunk_rays)
    summary = ScoreSummary.of(scores)
    if cfg.name == "argmax":
        index = argmax_first(scores)
        return Selection(
            candidates[index], index, scores[index].item(), m, summary, candidates=candidates, scores=scores
        )

    assert isinstance(scorer, ViewScorer)  # -OPT with a WholeViewScorer was refused above
    top = top_k_first(scores, cfg.opt.top_k)
    refined, kept = refine_poses(model, scorer, candidates[top], camera_box, intrinsics, cfg.opt, generators)
    pool = torch.cat([candidates[top], refined])
    pool_scores = score_poses(model, scorer, pool, intrinsics, cfg.score_chunk_rays)
    best = argmax_first(pool_scores)
    k = top.shape[0]
    origin = top[best] if best < k else top[kept[best - k]]
    trace = OptTrace(top, pool_scores[:k], refined, top[kept], pool_scores[k:])
    return Selection(
        pool[best], int(origin), pool_scores[best].item(), m, summary, best >= k, trace, candidates, scores
    )
