"""nvf/uncertainty scorers: NVF's per-pixel entropy (M7-M15) and its ablation switches (METHOD 11),
the baselines (M22-M24, M26), degenerate rays and gradients (METHOD 15.5), and the method classes."""

import math
from dataclasses import replace

import pytest
import torch
from beartype.roar import BeartypeCallHintViolation

from nvf.config import Bound, Correlation, DepthMode, EntropyConfig, EntropySampler
from nvf.methods import NVF, ActiveNeRF, Method, NeurAR
from nvf.model import RenderResult
from nvf.rendering import Samples, ray_sum, weights_from_alpha
from nvf.uncertainty import H_MIN, ViewScorer, ray_mixture
from nvf.uncertainty.baselines import ActiveRMAPScorer, AIRScorer, RenderedVarianceScorer, WDScorer
from nvf.uncertainty.entropy import (
    corrected_entropy,
    equivalent_depth,
    mixture_entropy_upper_bound,
    mixture_moment_matched_entropy,
    upper_bound_and_depth,
)
from nvf.uncertainty.nvf_entropy import NVFEntropyScorer
from pipeline.config.catalog import method_configs
from pipeline.config.method import MethodError, build_method, method_class

CFG = EntropyConfig()
H_MIN32 = torch.tensor(H_MIN).item()  # the floor as a float32 score


def render_result(alpha, ray_idx, n_rays, t_mid=None, rgb_s=None, variance=None, visibility=None):
    """A RenderResult from per-sample values, composited with M2/M3 (unit-length intervals)."""
    s = alpha.shape[0]
    t_mid = torch.arange(s, dtype=torch.float32) + 0.5 if t_mid is None else t_mid
    weights, trans = weights_from_alpha(alpha, ray_idx, n_rays)
    rgb_s = torch.full((s, 3), 0.5) if rgb_s is None else rgb_s
    acc = ray_sum(weights, ray_idx, n_rays)
    return RenderResult(
        samples=Samples(ray_idx, t_mid - 0.5, t_mid + 0.5, n_rays),
        sigma=-torch.log1p(-alpha.clamp(max=1 - 1e-7)),
        alpha=alpha,
        weights=weights,
        trans=trans,
        rgb_s=rgb_s,
        variance=torch.full((s, 3), 0.01) if variance is None else variance,
        visibility=torch.ones(s) if visibility is None else visibility,
        rgb=ray_sum(weights[:, None] * rgb_s, ray_idx, n_rays),
        depth=ray_sum(weights * t_mid, ray_idx, n_rays) / (acc + 1e-10),
        acc=acc,
    )


def random_result(counts=(4, 0, 1, 9, 3), seed=0):
    g = torch.Generator().manual_seed(seed)
    ray_idx = torch.repeat_interleave(torch.arange(len(counts)), torch.tensor(counts))
    s = ray_idx.numel()
    return render_result(
        torch.rand(s, generator=g),
        ray_idx,
        len(counts),
        t_mid=0.2 + 2.0 * torch.rand(s, generator=g).sort().values,
        rgb_s=torch.rand(s, 3, generator=g),
        variance=1e-4 + 0.1 * torch.rand(s, 3, generator=g),
        visibility=torch.rand(s, generator=g),
    )


def nvf_reference(result, cfg=CFG, d0=1.0, pixel_index=None):
    """H' assembled from the building blocks: bound (M10 | M12), depth (M15), correction (M14)."""
    samples = result.samples
    mix, eq_w = ray_mixture(
        result.alpha, result.rgb_s, result.variance, result.visibility, samples.ray_idx, samples.n_rays, cfg
    )
    h = (
        mixture_entropy_upper_bound(mix, cfg.logdet_coeff)
        if cfg.bound == "huber"
        else mixture_moment_matched_entropy(mix)
    )
    depth = equivalent_depth(
        eq_w, samples.t_mid, samples.ray_idx, samples.n_rays, cfg.depth_mode, pixel_index, cfg.chunk_rays
    )
    return h, depth, corrected_entropy(h, depth, d0, cfg.corr)


# ---------------------------------------------------------------- NVF (M7-M15)


@pytest.mark.parametrize("c, want", [(0.5, (3.769962, -2.650940)), (1.0, (3.086060, H_MIN))])
def test_nvf_table_values_through_the_scorer(c, want):
    """METHOD 7.4 through the whole per-ray pipeline: alpha = 1, v = 0 | 1, q = 0.01, depth >= d0
    (no correction), plus a ray without samples, which gets exactly H_min (M11, METHOD 15.5)."""
    result = render_result(
        torch.ones(2), torch.tensor([0, 1]), 3, t_mid=torch.tensor([2.0, 2.0]), visibility=torch.tensor([0.0, 1.0])
    )
    scores = NVFEntropyScorer(replace(CFG, logdet_coeff=c), d0=1.0).pixel_scores(result)
    assert scores[:2].tolist() == pytest.approx(want, abs=1e-5)
    assert scores[2].item() == H_MIN32


def test_nvf_correction_uses_equivalent_weights_depth():
    """(M13-M15) d from the equivalent weights w_bar (not w): H' = H_min + min(d/d0,1)^2 (H - H_min)."""
    alpha, v = torch.tensor([0.3, 0.9]), torch.tensor([0.0, 0.2])
    result = render_result(alpha, torch.tensor([0, 0]), 1, t_mid=torch.tensor([0.4, 0.6]), visibility=v)
    h, depth, _ = nvf_reference(result)
    a_bar = (v + 0.95 * (1 - v)) * alpha + 0.05 * (1 - v) * (1 - math.exp(-0.01))
    w_bar = torch.stack([a_bar[0], (1 - a_bar[0]) * a_bar[1]])
    assert depth.item() == pytest.approx(((w_bar * torch.tensor([0.4, 0.6])).sum() / w_bar.sum()).item(), abs=1e-6)
    assert depth.item() != pytest.approx(result.depth.item(), abs=1e-4)
    got = NVFEntropyScorer(CFG, d0=2.0).pixel_scores(result)
    assert got.item() == pytest.approx(H_MIN + (depth.item() / 2.0) ** 2 * (h.item() - H_MIN), abs=1e-5)


def test_nvf_matches_building_blocks():
    """The scorer is exactly M7-M15 composed, with the floor on rays without samples."""
    result = random_result()
    got = NVFEntropyScorer(CFG, d0=1.0).pixel_scores(result)
    _, _, want = nvf_reference(result)
    want[1] = H_MIN
    assert torch.allclose(got, want, atol=1e-6)
    assert (got >= H_MIN32).all()


def test_without_visibility_is_the_full_pipeline_with_v_one():
    """(METHOD 11, w/o Vis.) Only v changes, to 1; the visibility head is not requested."""
    result = random_result()
    scorer = NVFEntropyScorer(replace(CFG, use_visibility=False), d0=1.0)
    assert scorer.heads == frozenset({"variance"})
    got = scorer.pixel_scores(replace(result, visibility=None))
    want = NVFEntropyScorer(CFG, d0=1.0).pixel_scores(replace(result, visibility=torch.ones_like(result.alpha)))
    assert torch.allclose(got, want, atol=1e-6)
    assert not torch.allclose(got, NVFEntropyScorer(CFG, d0=1.0).pixel_scores(result), atol=1e-3)


def test_without_variance_is_the_full_pipeline_with_seen_q_bg():
    """(METHOD 11, w/o Var.) Only the seen variances change, to var_bg; the head is not requested."""
    result = random_result()
    scorer = NVFEntropyScorer(replace(CFG, use_variance=False), d0=1.0)
    assert scorer.heads == frozenset({"visibility"})
    got = scorer.pixel_scores(replace(result, variance=None))
    want = NVFEntropyScorer(CFG, d0=1.0).pixel_scores(replace(result, variance=torch.full_like(result.rgb_s, 1e-4)))
    assert torch.allclose(got, want, atol=1e-6)


def test_independent_rays_is_max_of_h_and_floor():
    """(METHOD 11, Ind. Rays) d0 = 0: H' = max(H, H_min); empty rays exactly H_min."""
    result = random_result()
    h, _, _ = nvf_reference(result)
    got = NVFEntropyScorer(CFG, d0=0.0).pixel_scores(result)
    want = h.clamp(min=H_MIN)
    want[1] = H_MIN
    assert torch.allclose(got, want, atol=1e-6)
    assert got[1].item() == H_MIN32


def test_component_wise_bound_reads_no_means():
    """(M10) The bound depends on weights and variances only, so NVF does not request the colour head;
    the Loose bound (M12) does, and its score changes with the means."""
    result = random_result()
    assert NVFEntropyScorer(CFG, d0=1.0).heads == frozenset({"variance", "visibility"})
    got = NVFEntropyScorer(CFG, d0=1.0).pixel_scores(replace(result, rgb_s=None))
    assert torch.equal(got, NVFEntropyScorer(CFG, d0=1.0).pixel_scores(result))
    loose = NVFEntropyScorer(replace(CFG, bound=Bound.moment_matched), d0=1.0)
    assert loose.heads == frozenset({"rgb", "variance", "visibility"})
    shifted = replace(result, rgb_s=torch.rand_like(result.rgb_s))
    assert not torch.allclose(loose.pixel_scores(shifted), loose.pixel_scores(result), atol=1e-3)


def test_loose_bound_only_changes_h():
    """(METHOD 11, Loose) bound=moment_matched swaps M10 for M12; depth, correction, floor unchanged."""
    result = random_result()
    cfg = replace(CFG, bound=Bound.moment_matched)
    h, depth, want = nvf_reference(result, cfg)
    _, depth_default, _ = nvf_reference(result)
    assert torch.equal(depth, depth_default)
    got = NVFEntropyScorer(cfg, d0=1.0).pixel_scores(result)
    want[1] = H_MIN
    assert torch.allclose(got, want, atol=1e-6)


@pytest.mark.parametrize("override", [dict(corr=Correlation.exp), dict(logdet_coeff=1.0)])
def test_other_switches_match_building_blocks(override):
    """(M13 corr=exp; M10 c = 1, D1)."""
    result = random_result()
    cfg = replace(CFG, **override)
    _, _, want = nvf_reference(result, cfg, d0=0.7)
    want[1] = H_MIN
    assert torch.allclose(NVFEntropyScorer(cfg, d0=0.7).pixel_scores(result), want, atol=1e-6)


def test_chunk_depth_mode():
    """(M15, D3) depth_mode=chunk: one depth per row-major pixel chunk; needs pixel_index."""
    result = random_result()
    cfg = replace(CFG, depth_mode=DepthMode.chunk, chunk_rays=2)
    pixel_index = torch.tensor([6, 7, 8, 9, 10])
    _, depth, want = nvf_reference(result, cfg, pixel_index=pixel_index)
    assert depth[0] == depth[1] and depth[2] == depth[3] and depth[0] != depth[2]
    want[1] = H_MIN
    assert torch.allclose(NVFEntropyScorer(cfg, d0=1.0).pixel_scores(result, pixel_index), want, atol=1e-6)
    with pytest.raises(ValueError, match="pixel_index"):
        NVFEntropyScorer(cfg, d0=1.0).pixel_scores(result)


@pytest.mark.parametrize(
    "override", [{}, dict(logdet_coeff=1.0), dict(use_visibility=False), dict(use_variance=False)], ids=str
)
def test_unpacked_bound_and_depth_equal_the_packed_mixture(override):
    """(M9, M10, M15) The scorer's fast path (no packed mixture) = M10 on ``ray_mixture`` and M15."""
    cfg = replace(CFG, **override)
    result = random_result(counts=(4, 0, 1, 9, 3, 0, 30), seed=3)
    s = result.samples
    v = result.visibility if cfg.use_visibility else None
    q = result.variance if cfg.use_variance else None
    mix, eq_w = ray_mixture(result.alpha, result.rgb_s, q, v, s.ray_idx, s.n_rays, cfg)
    h, depth = upper_bound_and_depth(eq_w, v, q, s.t_mid, s.ray_idx, s.n_rays, cfg)
    torch.testing.assert_close(h, mixture_entropy_upper_bound(mix, cfg.logdet_coeff), rtol=1e-6, atol=1e-6)
    torch.testing.assert_close(depth, equivalent_depth(eq_w, s.t_mid, s.ray_idx, s.n_rays), rtol=1e-6, atol=1e-7)


def test_nvf_gradients_match_building_blocks():
    """The -OPT planner backpropagates through H': the fast path has the reference's gradients."""
    result = random_result()
    leaves = {name: getattr(result, name).clone().requires_grad_() for name in ("alpha", "variance", "visibility")}
    result = replace(result, **leaves)
    got = torch.autograd.grad(NVFEntropyScorer(CFG, d0=1.0).pixel_scores(result).sum(), list(leaves.values()))
    want = torch.autograd.grad(nvf_reference(result)[2][[0, 2, 3, 4]].sum(), list(leaves.values()))
    for name, g, w in zip(leaves, got, want, strict=True):
        torch.testing.assert_close(g, w, rtol=1e-5, atol=1e-6, msg=name)


def test_batch_without_samples_is_the_floor():
    """(M11) A batch without samples scores H_min everywhere; with a graph it stays differentiable."""
    none = torch.zeros(0)
    result = render_result(none, torch.zeros(0, dtype=torch.long), 3, none, torch.zeros(0, 3), torch.zeros(0, 3), none)
    scorer = NVFEntropyScorer(CFG, d0=1.0)
    assert scorer.pixel_scores(result).tolist() == [H_MIN32] * 3
    scores = scorer.pixel_scores(replace(result, alpha=none.clone().requires_grad_()))
    assert scores.tolist() == [H_MIN32] * 3
    scores.sum().backward()
    with pytest.raises(ValueError, match="visibility"):
        scorer.pixel_scores(replace(result, visibility=None))


def test_invalid_nvf_settings():
    with pytest.raises((TypeError, BeartypeCallHintViolation)):  # outside the Bound enum: refused when built
        replace(CFG, bound="exact")
    with pytest.raises(ValueError):
        NVFEntropyScorer(CFG, d0=-1.0)


# ---------------------------------------------------------------- baselines (M22-M24, M26)


def two_rays():
    """Ray 0: alpha (0.5, 0.6) -> w (0.5, 0.3), w_bg 0.2, T (1, 0.5); ray 1: no samples."""
    return render_result(
        torch.tensor([0.5, 0.6]), torch.tensor([0, 0]), 2, variance=torch.tensor([[0.1, 0.2, 0.3], [1e-4, 1e-4, 1e-4]])
    )


def h(a):
    return -a * math.log(a + 1e-6) - (1 - a) * math.log(1 - a + 1e-6)


def test_wd_hand_computed():
    """(M22) -sum w ln w - w_bg ln w_bg; a ray that hits nothing scores 0."""
    got = WDScorer().pixel_scores(two_rays())
    want = -(0.5 * math.log(0.5) + 0.3 * math.log(0.3) + 0.2 * math.log(0.2))
    assert got.tolist() == pytest.approx([want, 0.0], abs=1e-6)


def test_activermap_hand_computed():
    """(M23) sum_i h(alpha_i); occlusion-weighted: sum_i T_i h(alpha_i)."""
    result = two_rays()
    assert ActiveRMAPScorer().pixel_scores(result).tolist() == pytest.approx([h(0.5) + h(0.6), 0.0], abs=1e-6)
    weighted = ActiveRMAPScorer(occlusion_weighted=True).pixel_scores(result)
    assert weighted.tolist() == pytest.approx([h(0.5) + 0.5 * h(0.6), 0.0], abs=1e-6)


def test_air_hand_computed():
    """(M24) mean over the ray's samples of T+_i h(alpha_i), inclusive T+ = (0.5, 0.2); sum option."""
    result = two_rays()
    total = 0.5 * h(0.5) + 0.2 * h(0.6)
    assert AIRScorer().pixel_scores(result).tolist() == pytest.approx([total / 2, 0.0], abs=1e-6)
    assert AIRScorer(reduce="sum").pixel_scores(result).tolist() == pytest.approx([total, 0.0], abs=1e-6)


def test_rendered_variance_hand_computed():
    """(M26) sum_i max(w_i mean_ch q_i, 1e-9): 0.5 * 0.2 + max(0.3 * 1e-4, 1e-9)."""
    got = RenderedVarianceScorer().pixel_scores(two_rays())
    assert got.tolist() == pytest.approx([0.1 + 3e-5, 0.0], abs=1e-7)
    floored = render_result(torch.tensor([0.0]), torch.tensor([0]), 1, variance=torch.full((1, 3), 0.1))
    assert RenderedVarianceScorer().pixel_scores(floored).item() == pytest.approx(1e-9)


# ---------------------------------------------------------------- all scorers


SCORING = ("wd", "activermap", "air", "activenerf", "neurar", "nvf")


def method(name: str, **settings) -> Method:
    """A method as its yaml declares it (conf/method), with ``settings`` changed."""
    return build_method({**method_configs()[name], **settings}, {"nvf.entropy": replace(CFG, d0=1.0)})


def scorers():
    out = [method(name).scorer() for name in SCORING]
    out += [method("activermap", occlusion_weighted=True).scorer(), method("air", reduce="sum").scorer()]
    out += [NVFEntropyScorer(replace(CFG, bound=Bound.moment_matched), 1.0), NVFEntropyScorer(CFG, 0.0)]
    return out


def degenerate_results():
    empty = torch.zeros(0, dtype=torch.long)
    yield "no samples at all", render_result(torch.zeros(0), empty, 3, t_mid=torch.zeros(0))
    yield "opaque samples", render_result(torch.ones(3), torch.tensor([0, 0, 1]), 2)
    yield "zero weights", render_result(torch.zeros(3), torch.tensor([0, 0, 1]), 3)
    yield "unseen opaque", render_result(torch.ones(2), torch.tensor([0, 1]), 2, visibility=torch.zeros(2))


@pytest.mark.parametrize("scorer", scorers(), ids=lambda s: s.name)
def test_degenerate_rays_no_nan(scorer):
    """METHOD 15.5: no NaN or inf on empty, opaque or zero-weight rays; empty rays get the floor."""
    for what, result in degenerate_results():
        scores = scorer.pixel_scores(result, torch.arange(result.samples.n_rays))
        assert scores.shape == (result.samples.n_rays,) and torch.isfinite(scores).all(), what
    scores = scorer.pixel_scores(next(degenerate_results())[1], None)
    assert scores.tolist() == [H_MIN32 if scorer.name == "nvf" else 0.0] * 3


@pytest.mark.parametrize("scorer", scorers(), ids=lambda s: s.name)
def test_gradients_finite(scorer):
    """Scores are differentiable in the per-sample render outputs (-OPT), with finite gradients,
    also through opaque (alpha = 1) and unseen (v = 0) samples."""
    base = random_result()
    alpha = base.alpha.clone()
    alpha[0], alpha[5] = 1.0, 0.0
    leaves = {
        "alpha": alpha.requires_grad_(),
        "rgb_s": base.rgb_s.clone().requires_grad_(),
        "variance": base.variance.clone().requires_grad_(),
        "visibility": base.visibility.clone().index_fill(0, torch.tensor([1]), 0.0).requires_grad_(),
    }
    samples = base.samples
    result = render_result(ray_idx=samples.ray_idx, n_rays=samples.n_rays, t_mid=samples.t_mid, **leaves)
    scorer.pixel_scores(result, torch.arange(base.samples.n_rays)).sum().backward()
    assert leaves["alpha"].grad is not None and leaves["alpha"].grad.abs().sum() > 0
    for name, leaf in leaves.items():
        assert leaf.grad is None or torch.isfinite(leaf.grad).all(), name


def test_method_classes():
    """Each method class builds its scorer (METHOD 12): Random has none; heads and sampler per method; the
    variance-head baselines carry their stage-1 loss (M25, M27), the others none."""
    random = method("random")
    assert random.scorer() is None and random.aux_loss is None
    heads = {
        "wd": frozenset(),
        "activermap": frozenset(),
        "air": frozenset(),
        "activenerf": frozenset({"variance"}),
        "neurar": frozenset({"variance"}),
        "nvf": frozenset({"variance", "visibility"}),
    }
    for name, want in heads.items():
        built = method(name)
        scorer = built.scorer()
        assert isinstance(scorer, ViewScorer) and scorer.name == name
        assert scorer.heads == want and scorer.sampler == "occupancy"
        assert (built.aux_loss is not None) == isinstance(built, ActiveNeRF | NeurAR)
    uniform = replace(method("nvf"), entropy=replace(CFG, d0=1.0, sampler=EntropySampler.uniform))
    assert uniform.scorer().sampler == "uniform"
    assert method("activermap", occlusion_weighted=True).scorer().occlusion_weighted
    assert method("air", reduce="sum").scorer().reduce == "sum"
    for name, settings in (("air", {"view_score": "topk"}), ("activenerf", {"variant": "B"})):
        with pytest.raises(MethodError, match="not implemented"):
            method(name, **settings)


def test_a_method_class_by_import_path():
    """``method._target_`` names a Method subclass; anything else is one line."""
    assert method_class("nvf.methods.NVF") is NVF
    for bad in ("nvf.methods.nothing", "no_such_module.Method", "nvf.config.TrainConfig", "NVF"):
        with pytest.raises(MethodError) as info:
            method_class(bad)
        assert "\n" not in str(info.value)


# ---------------------------------------------------------------- the reward split into terms (M10, M14)


@pytest.mark.parametrize(
    "override", [{}, {"logdet_coeff": 1.0}, {"use_visibility": False}, {"use_variance": False}, {"d0": 0}]
)
def test_pixel_terms_add_up_to_the_score(override):
    """(M10, M14) H_min + seen + unknown + background + mixing + correction is the scorer's H' per ray, for
    NVF and its ablations; the bound's four terms alone are M10's H, and the correction is H' - H."""
    d0 = float(override.pop("d0", 1.0))
    scorer = NVFEntropyScorer(replace(CFG, **override), d0)
    result = random_result()
    terms = scorer.pixel_terms(result)
    assert set(terms) == {"seen", "unknown", "background", "mixing", "correction"}
    total = H_MIN + sum(terms.values())
    torch.testing.assert_close(total, scorer.pixel_scores(result), atol=1e-5, rtol=0)
    h, _, _ = nvf_reference(result, scorer.cfg)
    bound = H_MIN + sum(terms[name] for name in ("seen", "unknown", "background", "mixing"))
    with_samples = torch.bincount(result.samples.ray_idx, minlength=result.samples.n_rays) > 0
    torch.testing.assert_close(bound[with_samples], h[with_samples], atol=1e-5, rtol=0)
    if not scorer.cfg.use_visibility:
        assert (terms["unknown"] == 0).all()


@pytest.mark.parametrize("v, unknown_weight", [(0.0, 0.950498), (1.0, 0.0)])
def test_pixel_terms_of_the_table(v, unknown_weight):
    """METHOD 7.4 (alpha = 1, q = 0.01): with c = 0.5 the unknown component is worth (3/2) ln(1/1e-4) =
    13.8155 nats per unit of weight above the floor, the background 0; the seen one (3/2) ln(0.01/1e-4)."""
    result = render_result(torch.ones(1), torch.zeros(1, dtype=torch.long), 1, visibility=torch.tensor([v]))
    terms = NVFEntropyScorer(CFG, 0.0).pixel_terms(result)
    assert terms["unknown"].item() == pytest.approx(unknown_weight * 1.5 * math.log(1e4), abs=1e-4)
    assert terms["seen"].item() == pytest.approx(v * 1.5 * math.log(100.0), abs=1e-4)
    assert terms["background"].item() == pytest.approx(0.0, abs=1e-4)


def test_pixel_terms_refuse_the_loose_bound():
    """(M12) the moment-matched bound has no per-component split."""
    with pytest.raises(ValueError, match="bound=huber"):
        NVFEntropyScorer(replace(CFG, bound=Bound.moment_matched), 1.0).pixel_terms(random_result())
