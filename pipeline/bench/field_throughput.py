"""``python -m pipeline.bench field [--threads 2] [--iters 5] [--device auto]``: field throughput on a device
(``auto``: CUDA where present, else this CPU; the C++ variants only on the CPU).

Measures, side by side in one run, for each backbone variant (hash grid with the paper's 2^19
table on the torch and C++ backends, the CPU-budget hash grid, dense grids):

- training samples/s: forward + backward + Adam step of the backbone (density + colour heads) on
  ``rays x samples_per_ray`` ray-coherent samples, with the time split into encoding forward,
  encoding backward, the rest of forward/backward (MLPs), and the optimiser step;
- inference samples/s: ``no_grad``, density + colour + variance + visibility heads, in chunks;
- ``fraction_of_limit``: MLP FLOPs/sample x samples/s over the ``[N,64] x [64,64]`` matmul rate
  measured just before the variant, i.e. how close the variant runs to pure-matmul speed.

Every rate is given twice: from the median wall time, and (``*_cpu``) from the median process CPU
time divided by the thread count, which is robust to other jobs sharing the cores. Writes
``results/bench/field.json`` and prints a table.
"""

import os
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import torch
from jaxtyping import Float
from torch import Tensor

from nvf.config import FieldConfig, FieldKind, HashBackend
from nvf.device import resolve_device, synchronize
from nvf.encoding import cpp_extension
from nvf.field import HEADS, RadianceField, spherical_harmonics
from pipeline.bench._report import report_path, write_report
from pipeline.cli import ArgumentParser, description, fail
from pipeline.config.paths import paths_from_args

AABB = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
CPU = torch.device("cpu")
CPU_BUDGET_LOG2 = 15


def variants() -> dict[str, FieldConfig]:
    """The backbones compared: paper hash grid on both backends, the CPU-budget hash grid, dense grids."""
    return {
        "hash2^19-torch": FieldConfig(backend=HashBackend.torch),
        "hash2^19-cpp": FieldConfig(backend=HashBackend.cpp),
        f"hash2^{CPU_BUDGET_LOG2}-torch": FieldConfig(log2_hashmap_size=CPU_BUDGET_LOG2, backend=HashBackend.torch),
        f"hash2^{CPU_BUDGET_LOG2}-cpp": FieldConfig(log2_hashmap_size=CPU_BUDGET_LOG2, backend=HashBackend.cpp),
        "hash2^17-cpp": FieldConfig(log2_hashmap_size=17, backend=HashBackend.cpp),
        "dense128x32-cpp": FieldConfig(
            kind=FieldKind.densegrid, dense_resolution=128, dense_features=32, backend=HashBackend.cpp
        ),
        "dense64x32-cpp": FieldConfig(
            kind=FieldKind.densegrid, dense_resolution=64, dense_features=32, backend=HashBackend.cpp
        ),
    }


def ray_samples(
    n_rays: int, per_ray: int, generator: torch.Generator
) -> tuple[Float[Tensor, "S 3"], Float[Tensor, "S 3"]]:
    """Points marched along random rays through the AABB (step 4 sqrt(3)/1000 as in M6), and their dirs
    (on the CPU)."""
    origins = torch.rand(n_rays, 3, generator=generator) * 1.6 - 0.8
    dirs = torch.nn.functional.normalize(torch.randn(n_rays, 3, generator=generator), dim=-1)
    t = torch.arange(per_ray, dtype=torch.float32) * (4.0 * 3.0**0.5 / 1000.0)
    points = origins[:, None] + t[None, :, None] * dirs[:, None]
    return points.reshape(-1, 3), dirs[:, None].expand(-1, per_ray, -1).reshape(-1, 3)


def median_seconds(fn: Callable[[], object], iters: int, reduce: Callable = statistics.median) -> tuple[float, float]:
    """Median (or ``reduce``) wall seconds and process CPU seconds per thread of ``fn`` after a warm-up call.

    The CPU figure is robust to other jobs sharing the cores (it is what the call would take alone
    with perfect threading); the wall figure is what this run experienced.
    """
    fn()
    synchronize()
    wall, cpu = [], []
    for _ in range(iters):
        start, start_cpu = time.perf_counter(), time.process_time()
        fn()
        synchronize()
        wall.append(time.perf_counter() - start)
        cpu.append((time.process_time() - start_cpu) / torch.get_num_threads())
    return reduce(wall), reduce(cpu)


def matmul_gflops(n: int, width: int, iters: int, device: torch.device = CPU) -> tuple[float, float]:
    """Best dense ``[n, width] x [width, width]`` float32 matmul GFLOP/s on ``device`` (wall, CPU): the MLPs'
    roofline."""
    a, b = torch.randn(n, width, device=device), torch.randn(width, width, device=device)
    out = torch.empty(n, width, device=device)
    wall, cpu = median_seconds(lambda: torch.mm(a, b, out=out), iters * 10, reduce=min)
    return 2.0 * n * width * width / wall / 1e9, 2.0 * n * width * width / cpu / 1e9


def mlp_flops(field: RadianceField, heads: frozenset[str], train: bool) -> float:
    """FLOPs per sample of the MLPs evaluated for ``heads`` (x3 for forward + backward)."""
    modules = [field.density_mlp]
    modules += [field.color_head] if "rgb" in heads else []
    modules += [field.variance_head] if "variance" in heads else []
    modules += [field.vis_position, field.vis_head] if "visibility" in heads else []
    macs = sum(p.numel() for m in modules for p in m.parameters() if p.dim() == 2)
    return 2.0 * macs * (3.0 if train else 1.0)


def bench_variant(
    cfg: FieldConfig, rays: int, per_ray: int, chunk: int, iters: int, device: torch.device = CPU
) -> dict[str, float | int]:
    """Training and inference throughput of one field configuration on ``device``, with a per-phase time split."""
    generator = torch.Generator().manual_seed(0)
    field = RadianceField(AABB, cfg).to(device)
    optimizer = torch.optim.Adam(field.parameter_groups()["backbone"], lr=1e-2, eps=1e-15, fused=True)
    x, d = (t.to(device) for t in ray_samples(rays, per_ray, generator))
    target = torch.rand(x.shape[0], 3, generator=generator).to(device)
    n = x.shape[0]
    heads_train = frozenset({"rgb"})
    phases: dict[str, list[float]] = {"encode_fwd": [], "encode_bwd": [], "mlp_fwd_bwd": [], "optimizer": []}

    sh = spherical_harmonics(d)

    def train_step() -> None:
        """The training step split in phases: the MLPs run on a detached copy of the features."""
        t0 = time.perf_counter()
        feats = field.encoding(field.normalize(x))
        t1 = time.perf_counter()
        leaf = feats.detach().requires_grad_()
        h = field.density_mlp(leaf)
        rgb = torch.sigmoid(field.color_head(torch.cat([sh, h[:, 1:]], dim=-1)))
        loss = ((rgb - target) ** 2).mean() + 1e-3 * torch.exp(h[:, 0]).mean()
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        t2 = time.perf_counter()
        feats.backward(leaf.grad)
        t3 = time.perf_counter()
        optimizer.step()
        t4 = time.perf_counter()
        for key, seconds in zip(phases, (t1 - t0, t3 - t2, t2 - t1, t4 - t3), strict=True):
            phases[key].append(seconds)

    def full_train_step() -> None:
        out = field(x, d, heads_train)
        loss = ((out.rgb - target) ** 2).mean() + 1e-3 * out.sigma.mean()
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()

    train_s, train_cpu = median_seconds(full_train_step, iters)
    median_seconds(train_step, iters)
    split = {key: statistics.median(values[1:]) for key, values in phases.items()}

    xi, di = (t.to(device) for t in ray_samples(2 * rays, per_ray, generator))

    def infer(heads: frozenset[str]) -> Callable[[], None]:
        @torch.no_grad()
        def run() -> None:
            for start in range(0, xi.shape[0], chunk):
                field(xi[start : start + chunk], di[start : start + chunk], heads)

        return run

    @torch.no_grad()
    def infer_encoding() -> None:
        for start in range(0, xi.shape[0], chunk):
            field.encoding(field.normalize(xi[start : start + chunk]))

    infer_s, infer_cpu = median_seconds(infer(HEADS), iters)
    infer_rgb_s, infer_rgb_cpu = median_seconds(infer(frozenset({"rgb"})), iters)
    infer_enc_s, _ = median_seconds(infer_encoding, iters)
    m = xi.shape[0]
    return {
        "params": sum(p.numel() for p in field.parameters()),
        "train_samples_per_s": n / train_s,
        "train_samples_per_s_cpu": n / train_cpu,
        "infer_samples_per_s": m / infer_s,
        "infer_samples_per_s_cpu": m / infer_cpu,
        "infer_rgb_samples_per_s": m / infer_rgb_s,
        "infer_rgb_samples_per_s_cpu": m / infer_rgb_cpu,
        "train_ms": 1e3 * train_s,
        **{f"train_{key}_ms": 1e3 * value for key, value in split.items()},
        "infer_ms_per_1e5": 1e8 * infer_s / m,
        "infer_encoding_ms_per_1e5": 1e8 * infer_enc_s / m,
        "mlp_flops_train": mlp_flops(field, heads_train, train=True),
        "mlp_flops_infer": mlp_flops(field, HEADS, train=False),
        "mlp_flops_infer_rgb": mlp_flops(field, frozenset({"rgb"}), train=False),
    }


def main(argv: list[str]) -> None:
    parser = ArgumentParser(prog="python -m pipeline.bench field", description=description(__doc__))
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--iters", type=int, default=3)
    parser.add_argument("--rays", type=int, default=1024)
    parser.add_argument("--samples-per-ray", type=int, default=25)
    parser.add_argument("--chunk", type=int, default=8192)
    parser.add_argument("--only", nargs="*", default=None, help="variant names to run (default: all)")
    parser.add_argument("--device", default="auto", help="auto (CUDA where present), cpu, cuda or cuda:N")
    parser.add_argument(
        "--out", type=Path, default=None, help="JSON report path (default: ${paths.results}/bench/field.json)"
    )
    parser.add_argument("overrides", nargs="*", metavar="KEY=VALUE", help="paths overrides, e.g. paths.results=results")
    args = parser.parse_intermixed_args(argv)
    cores = len(os.sched_getaffinity(0))
    for name, value, top in (
        ("--threads", args.threads, cores),
        ("--iters", args.iters, 1000),
        ("--rays", args.rays, 1 << 20),
        ("--samples-per-ray", args.samples_per_ray, 1024),
        ("--chunk", args.chunk, 1 << 22),
    ):
        if not 1 <= value <= top:
            fail(f"{name} {value}: must be 1..{top}" + (" (this machine's cores)" if name == "--threads" else ""))
    unknown = [name for name in args.only or [] if name not in variants()]
    if args.only is not None and (unknown or not args.only):
        fail(f"--only {' '.join(unknown or args.only) or '(none)'}: name variants of {', '.join(variants())}")
    try:  # bad input is one line before the benchmark runs, not after
        out = report_path(args.out, paths_from_args(args.overrides, ("paths.results",))["results"], "field")
    except ValueError as err:
        fail(str(err))
    torch.set_num_threads(args.threads)
    try:
        device = resolve_device(args.device)
    except RuntimeError:
        fail(f"--device {args.device!r}: must be auto, cpu, cuda or cuda:N")
    if device.type == "cuda" and not torch.cuda.is_available():
        fail(f"--device {args.device}: torch sees no CUDA device here; use --device auto or cpu")
    cpp_available = device.type == "cpu" and cpp_extension() is not None
    results = {}
    for name, cfg in variants().items():
        if args.only and name not in args.only:
            continue
        if cfg.backend == "cpp" and not cpp_available:
            continue
        # The matmul roofline is re-measured next to each variant: the cores are shared and load drifts.
        gflops, gflops_cpu = matmul_gflops(args.rays * args.samples_per_ray, 64, args.iters, device)
        r = bench_variant(cfg, args.rays, args.samples_per_ray, args.chunk, args.iters, device)
        r["matmul_gflops_64"], r["matmul_gflops_64_cpu"] = gflops, gflops_cpu
        for key in ("train", "infer", "infer_rgb"):
            flops = r[f"mlp_flops_{key}"]
            r[f"fraction_of_limit_{key}"] = flops * r[f"{key}_samples_per_s"] / (gflops * 1e9)
            r[f"fraction_of_limit_{key}_cpu"] = flops * r[f"{key}_samples_per_s_cpu"] / (gflops_cpu * 1e9)
        results[name] = r
        print(
            f"{name:16s} {r['params'] / 1e6:6.2f}M par | train {r['train_samples_per_s'] / 1e6:5.3f} M/s "
            f"(cpu {r['train_samples_per_s_cpu'] / 1e6:5.3f}) {r['train_ms']:6.1f} ms = enc fwd "
            f"{r['train_encode_fwd_ms']:5.1f} + enc bwd {r['train_encode_bwd_ms']:5.1f} + mlp "
            f"{r['train_mlp_fwd_bwd_ms']:5.1f} + adam {r['train_optimizer_ms']:5.1f} | infer all heads "
            f"{r['infer_samples_per_s'] / 1e6:5.3f} M/s (cpu {r['infer_samples_per_s_cpu'] / 1e6:5.3f}; enc "
            f"{r['infer_encoding_ms_per_1e5']:5.1f} of {r['infer_ms_per_1e5']:6.1f} ms/1e5), rgb only "
            f"{r['infer_rgb_samples_per_s'] / 1e6:5.3f} M/s (cpu {r['infer_rgb_samples_per_s_cpu'] / 1e6:5.3f}) | "
            f"frac train {r['fraction_of_limit_train_cpu']:.2f} infer {r['fraction_of_limit_infer_cpu']:.2f} "
            f"(matmul {gflops_cpu:.0f} GFLOP/s)",
            flush=True,
        )
    report = {
        "device": str(device),
        "torch_threads": args.threads,
        "batch_samples": args.rays * args.samples_per_ray,
        "infer_chunk": args.chunk,
        "cpp_available": cpp_available,
        "goals": {"train_samples_per_s": 1e6, "infer_samples_per_s": 3e6},
        "variants": results,
    }
    write_report(report, out)
    print(f"wrote {out}")
