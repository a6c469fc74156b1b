"""The field floor of a stage-1 iteration (``python -m pipeline.bench train``): the kept-sample rate if an
iteration cost only the field's own work, and the MLP floor, the same with only the MLPs' layers."""

import torch

from nvf.model import SceneModel
from nvf.observations import Observations
from pipeline.bench._models import RGB
from pipeline.bench.field_throughput import median_seconds


def field_floor(
    model: SceneModel,
    obs: Observations,
    rays: int,
    per_iter: tuple[float, float],
    update_every: int,
    generator: torch.Generator,
    repeats: int,
) -> dict[str, float | int]:
    """The field's own work in a stage-1 iteration, timed apart on one batch of ``rays`` training rays
    (median of ``repeats``, wall and CPU): the skipping pass's ``no_grad`` density and encoding on the
    batch's marched samples; forward + backward of density and colour on its kept samples, reusing their
    encoding as training does; one occupancy update (every cell, as in warm-up). Scaled per sample to
    ``per_iter`` (the training's mean kept and marched samples per iteration), with the update spread over
    ``update_every`` iterations, this gives ``train_samples_per_s_field_floor``: the kept-sample rate if
    marching, volume rendering, the loss and Adam cost nothing. ``train_samples_per_s_mlp_floor``: the same
    with only the MLPs' layers on the same rows (density MLP and colour head forward + backward on the kept
    samples, the density MLP on the marched samples and on every grid cell), i.e. if the hash encoding also
    cost nothing. Leaves the occupancy grid updated once more."""
    origins, dirs, _, _ = obs.sample_rays(rays, generator)
    with torch.no_grad():
        marched = model.grid.march(origins, dirs, jitter=True, generator=generator).positions(origins, dirs)
        kept = model.render(origins, dirs, train=True, generator=generator).samples
        kept_x, kept_d = kept.positions(origins, dirs), dirs[kept.ray_idx]
        encoded = model.field.density_and_encoding(kept_x)[2]

    def train_field() -> None:
        model.field.zero_grad(set_to_none=True)
        out = model.field(kept_x, kept_d, RGB, encoded=encoded)
        (out.rgb.sum() + out.sigma.sum()).backward()

    def skip_density() -> None:
        with torch.no_grad():
            model.field.density_and_encoding(marched)

    def grid_update() -> None:
        with torch.no_grad():
            model.update_grid(0, generator)

    field = model.field
    kept_encoded = encoded.clone().requires_grad_()
    first_layer = field.color_head[0]
    assert isinstance(first_layer, torch.nn.Linear), "an MLP starts with a linear layer"
    device = model.aabb.device
    kept_head_in = torch.randn(kept.num_samples, first_layer.in_features, requires_grad=True, device=device)
    marched_encoded = torch.randn(marched.shape[0], field.encoding.out_dim, device=device)
    cell_encoded = torch.randn(model.grid.resolution**3, field.encoding.out_dim, device=device)

    def mlp_fwd_bwd() -> None:
        field.zero_grad(set_to_none=True)
        (field.density_mlp(kept_encoded).sum() + field.color_head(kept_head_in).sum()).backward()

    def mlp_skip_density() -> None:
        with torch.no_grad():
            field.density_mlp(marched_encoded)

    def mlp_grid_update() -> None:
        with torch.no_grad():
            field.density_mlp(cell_encoded)

    work = {
        "field": (("fwd_bwd", train_field), ("skip_density", skip_density), ("grid_update", grid_update)),
        "mlp": (("fwd_bwd", mlp_fwd_bwd), ("skip_density", mlp_skip_density), ("grid_update", mlp_grid_update)),
    }
    r: dict[str, float | int] = {
        "field_floor_kept_samples": kept.num_samples,
        "field_floor_marched_samples": marched.shape[0],
    }
    kept_per_iter, marched_per_iter = per_iter
    for floor, parts in work.items():
        timed = {name: median_seconds(fn, repeats) for name, fn in parts}
        for i, suffix in enumerate(("", "_cpu")):
            seconds = (
                timed["fwd_bwd"][i] * kept_per_iter / kept.num_samples
                + timed["skip_density"][i] * marched_per_iter / marched.shape[0]
                + timed["grid_update"][i] / update_every
            )
            r[f"train_samples_per_s_{floor}_floor{suffix}"] = kept_per_iter / seconds
        for name, (wall, _) in timed.items():
            r[f"{floor}_floor_{name}_ms"] = 1e3 * wall
    field.zero_grad(set_to_none=True)
    return r
