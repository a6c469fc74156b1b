"""Hash-grid and dense-grid encodings (METHOD.md section 3: levels, dense vs hashed indexing, trilinear)."""

import inspect

import pytest
import torch
import torch.nn.functional as F

from nvf.densegrid import DenseGridEncoding
from nvf.encoding import HashEncoding, cpp_extension, level_resolutions

PI = (1, 2654435761, 805459861)


def _points(n: int) -> torch.Tensor:
    """Random points, some outside [0,1]^3 (clamped by the encoding) and some exactly on the faces."""
    u = torch.rand(n, 3) * 1.2 - 0.1
    u[:5] = torch.tensor([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [1.0, 0.5, 0.0], [0.25, 1.0, 0.75], [0.5, 0.5, 0.5]])
    return u


def test_public_signature():
    """HashEncoding(num_levels, features_per_level, log2_hashmap_size, base_resolution, max_resolution)."""
    names = list(inspect.signature(HashEncoding).parameters)
    assert names[:5] == ["num_levels", "features_per_level", "log2_hashmap_size", "base_resolution", "max_resolution"]


def test_paper_levels_and_table():
    """METHOD 3: N_l = floor(16 b^l), b = 32^(1/15); levels with <= 2^19 vertices are dense."""
    res = level_resolutions(16, 16, 512)
    assert res == [16, 20, 25, 32, 40, 50, 64, 80, 101, 128, 161, 203, 256, 322, 406, 512]
    enc = HashEncoding(16, 2, 19, 16, 512, backend="torch")
    assert enc.n_dense == 7  # 65^3 <= 2^19 < 81^3
    assert enc.level_sizes[:7] == [(r + 1) ** 3 for r in res[:7]] and enc.level_sizes[7:] == [2**19] * 9
    assert enc.table.shape == (sum(enc.level_sizes), 2)
    assert enc.table.abs().max() <= 1e-4  # U(-1e-4, 1e-4)
    assert enc(torch.rand(10, 3)).shape == (10, 32)


def test_corner_indices_match_integer_reference():
    """Dense levels: x + y (N+1) + z (N+1)^2; hashed: (x*pi_0 ^ y*pi_1 ^ z*pi_2) mod T in exact integers."""
    enc = HashEncoding(8, 2, 12, 4, 64, backend="torch")
    assert 0 < enc.n_dense < enc.num_levels
    u = torch.rand(64, 3)
    idx, weights = enc.corner_indices(u)
    torch.testing.assert_close(weights.sum(-1), torch.ones(64, 8))
    offsets = [sum(enc.level_sizes[:i]) for i in range(enc.num_levels)]
    for n in range(0, 64, 7):
        for level, res in enumerate(enc.resolutions):
            cell = [min(int((u[n, k] * res).floor()), res - 1) for k in range(3)]
            expected = []
            for a in (0, 1):
                for b in (0, 1):
                    for c in (0, 1):
                        x, y, z = cell[0] + a, cell[1] + b, cell[2] + c
                        if level < enc.n_dense:
                            expected.append(x + y * (res + 1) + z * (res + 1) ** 2)
                        else:
                            expected.append((x * PI[0] ^ y * PI[1] ^ z * PI[2]) % enc.table_size)
            assert idx[n, level].tolist() == [offsets[level] + e for e in expected]


def test_trilinear_interpolation_at_vertices_and_edges():
    """At a lattice vertex the encoding returns that vertex's features; along an edge it is linear."""
    enc = HashEncoding(2, 2, 10, 4, 8, backend="torch")  # 5^3 and 9^3 vertices: both dense
    with torch.no_grad():
        enc.table.normal_()
    vertex = torch.tensor([[0.25, 0.5, 0.75]])  # vertex (1, 2, 3) of level 0 (N = 4)
    row = 1 + 2 * 5 + 3 * 25
    torch.testing.assert_close(enc(vertex)[0, :2], enc.table[row])
    a, b = torch.tensor([[0.25, 0.5, 0.75]]), torch.tensor([[0.5, 0.5, 0.75]])
    mid = enc(0.7 * a + 0.3 * b)[0, :2]
    torch.testing.assert_close(mid, 0.7 * enc(a)[0, :2] + 0.3 * enc(b)[0, :2])


def test_input_gradients_torch_backend():
    """Gradients with respect to the points (needed by -OPT, METHOD 14) match finite differences."""
    enc = HashEncoding(4, 2, 10, 4, 16, backend="torch").double()
    with torch.no_grad():
        enc.table.normal_()
    u = (torch.rand(6, 3, dtype=torch.float64) * 0.8 + 0.1).requires_grad_()
    assert not enc.uses_cpp(u)
    assert torch.autograd.gradcheck(enc, (u,), eps=1e-6, atol=1e-5)


@pytest.mark.parametrize("log2", [12, 19])
def test_cpp_matches_torch(log2):
    """The C++ kernel computes the torch reference's values and table gradients (hashed and dense levels)."""
    if cpp_extension() is None:
        pytest.skip("C++ hash-grid kernel unavailable (no compiler or ninja)")
    ref = HashEncoding(16, 2, log2, 16, 512, backend="torch")
    fast = HashEncoding(16, 2, log2, 16, 512, backend="cpp")
    with torch.no_grad():
        ref.table.normal_()
    fast.load_state_dict(ref.state_dict())
    u = _points(3000)
    assert fast.uses_cpp(u)
    out_ref, out_fast = ref(u), fast(u)
    torch.testing.assert_close(out_fast, out_ref, rtol=1e-5, atol=1e-5)
    grad = torch.randn_like(out_ref)
    out_ref.backward(grad)
    out_fast.backward(grad)
    torch.testing.assert_close(fast.table.grad, ref.table.grad, rtol=1e-4, atol=1e-4)
    u_ref, u_fast = u.clone().requires_grad_(), u.clone().requires_grad_()
    (ref(u_ref) * grad).sum().backward()
    (fast(u_fast) * grad).sum().backward()
    torch.testing.assert_close(u_fast.grad, u_ref.grad, rtol=1e-3, atol=1e-3)


@pytest.mark.parametrize("backend", ["torch", "cpp"])
def test_known_output_gives_the_same_values_and_gradients(backend):
    """``forward(u, known=...)`` (the renderer's skipping pass reused) equals a fresh forward, in
    values, table gradients and point gradients."""
    if backend == "cpp" and cpp_extension() is None:
        pytest.skip("C++ hash-grid kernel unavailable (no compiler or ninja)")
    enc = HashEncoding(8, 2, 12, 4, 64, backend=backend)
    points = _points(500)
    with torch.no_grad():
        enc.table.normal_()
        known = enc(points)
    grad = torch.randn_like(known)
    results = []
    for reuse in (False, True):
        enc.table.grad = None
        u = points.clone().requires_grad_()
        out = enc(u, known=known if reuse else None)
        (out * grad).sum().backward()
        results.append((out.detach(), enc.table.grad.clone(), u.grad))
    for fresh, reused in zip(*results, strict=True):
        torch.testing.assert_close(reused, fresh)


def test_backend_selection():
    """torch forced; auto uses C++ for float32 CPU points when it builds; unknown names rejected."""
    assert not HashEncoding(4, 2, 10, 4, 16, backend="torch").uses_cpp(torch.rand(3, 3))
    auto = HashEncoding(4, 2, 10, 4, 16, backend="auto")
    assert not auto.uses_cpp(torch.rand(3, 3, dtype=torch.float64))
    assert auto.uses_cpp(torch.rand(3, 3, requires_grad=True)) == (cpp_extension() is not None)
    with pytest.raises(ValueError):
        HashEncoding(4, 2, 10, 4, 16, backend="cuda")


@pytest.mark.parametrize("backend", ["torch", "cpp"])
def test_densegrid_equals_grid_sample(backend):
    """The dense grid is trilinear interpolation: F.grid_sample(align_corners=True) on its lattice."""
    if backend == "cpp" and cpp_extension() is None:
        pytest.skip("C++ hash-grid kernel unavailable")
    enc = DenseGridEncoding(resolution=9, features=5, backend=backend)
    with torch.no_grad():
        enc.table.normal_()
    u = torch.rand(200, 3)
    expected = F.grid_sample(enc.grid()[None], (2 * u - 1).view(1, -1, 1, 1, 3), align_corners=True)
    out = enc(u)
    assert out.shape == (200, 5) and enc.out_dim == 5
    torch.testing.assert_close(out, expected.view(5, -1).T, rtol=1e-5, atol=1e-5)
    out.square().sum().backward()
    assert enc.table.grad is not None and torch.isfinite(enc.table.grad).all()


def test_densegrid_input_gradients():
    """Gradients flow to the input points of the dense grid (torch path)."""
    enc = DenseGridEncoding(resolution=6, features=3)
    with torch.no_grad():
        enc.table.normal_()
    u = torch.rand(10, 3, requires_grad=True)
    enc(u).sum().backward()
    assert u.grad is not None and torch.isfinite(u.grad).all() and u.grad.abs().sum() > 0


@pytest.mark.parametrize("log2", [12, 19])
def test_prefetch_distance_changes_no_bit(log2):
    """The C++ kernel's software prefetch (``prefetch_ahead``) leaves its outputs, table gradients and point
    gradients bitwise unchanged: it only requests table rows early."""
    if cpp_extension() is None:
        pytest.skip("C++ hash-grid kernel unavailable (no compiler or ninja)")
    enc = HashEncoding(16, 2, log2, 16, 512, backend="cpp")
    with torch.no_grad():
        enc.table.normal_()
    u = _points(3000)
    grad = torch.randn(3000, enc.out_dim)
    results = []
    for ahead in (0, 3, 16):
        enc.prefetch_ahead = ahead
        points = u.clone().requires_grad_()
        out = enc(points)
        table_grad, point_grad = torch.autograd.grad(out, [enc.table, points], grad)
        results.append((out, table_grad, point_grad))
    for other in results[1:]:
        for want, got in zip(results[0], other, strict=True):
            assert torch.equal(want, got)
