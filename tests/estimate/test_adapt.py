"""The fit check and the basis learned from a log's own SGBM maps (estimate/adapt.py)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pcainterp_stream.estimate import adapt, rougher
from pcainterp_stream.estimate.basis import builtin_basis
from pcainterp_stream.estimate.prior import LocalPrior, evidence_noise, evidence_sigma
from pcainterp_stream.pipeline.processor import ProcessorConfig, resolve_settings

SIZE = (48, 64)


def _scene(shift: float) -> np.ndarray:
    """A smooth disparity map with a step: what a basis of such maps reproduces exactly."""
    rows, cols = np.mgrid[0 : SIZE[0], 0 : SIZE[1]].astype(np.float32)
    return (10.0 + 0.1 * rows + shift * (cols > 30)).astype(np.float32)


def _points(count: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.stack(
        [rng.uniform(2, SIZE[1] - 3, count), rng.uniform(2, SIZE[0] - 3, count)], axis=1
    ).astype(np.float32)


def _measure(reference: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    return reference[pixels[:, 1].round().astype(int), pixels[:, 0].round().astype(int)]


def test_held_out_pixels_are_valid_and_away_from_the_measurements() -> None:
    reference = _scene(4.0)
    reference[:5] = np.nan
    pixels = np.array([[20.0, 20.0]], dtype=np.float32)
    flat = adapt.heldout_pixels(reference, pixels, samples=100_000)
    rows, cols = np.divmod(flat, SIZE[1])
    assert np.all(rows >= 5)
    assert not np.any((np.abs(rows - 20) <= 2) & (np.abs(cols - 20) <= 2))
    assert flat.size == np.isfinite(reference).sum() - 25
    assert adapt.heldout_pixels(reference, pixels, samples=50).size == 50


def test_check_scores_the_prior_against_linear_and_nearest() -> None:
    reference = _scene(4.0)
    pixels = _points(40, seed=1)
    disparities = _measure(reference, pixels)
    perfect = adapt.check_frame(reference, reference, pixels, disparities)
    assert perfect.prior == 0.0
    assert perfect.linear > 0.0
    assert perfect.nearest > perfect.linear * 0.5
    flat_map = np.full(SIZE, 10.0, dtype=np.float32)
    poor = adapt.FitCheck.combine([adapt.check_frame(flat_map, reference, pixels, disparities)])
    assert poor.frames == 1
    assert poor.ratio > 1.0
    assert not poor.fits
    assert "x linear" in poor.describe()


def test_a_check_with_sgbm_s_left_band_empty_says_the_columns_it_covered() -> None:
    """Bug hunt 9B F6: SGBM's left band (no values unless it matches the whole width) is never
    held out, so the check scored only the columns right of it, and its line did not say so.
    Before: "0.99x linear ... on held-out SGBM pixels (...)" whatever the band."""
    reference = _scene(4.0)
    pixels = _points(40, seed=1)
    disparities = _measure(reference, pixels)
    estimate = np.full(SIZE, 10.0, dtype=np.float32)
    whole = adapt.FitCheck.combine([adapt.check_frame(estimate, reference, pixels, disparities)])
    assert whole.first_column == 0
    assert "x nearest on held-out SGBM pixels (" in whole.describe()
    banded = reference.copy()
    banded[:, :20] = np.nan  # a band of 20 px, as SGBM leaves min_disparity + num_disparities
    frames = [adapt.check_frame(estimate, banded, pixels, disparities)] * 2
    check = adapt.FitCheck.combine(frames)
    assert check.first_column == 20
    assert "x nearest on held-out SGBM pixels in columns >= 20 (" in check.describe()
    # a frame that reaches further left sets the pooled check's first column
    pooled = adapt.FitCheck.combine(
        [*frames, adapt.HeldOut.of(reference, pixels, disparities).score(estimate)]
    )
    assert pooled.first_column == 0
    assert "columns" not in pooled.describe()
    # a band narrower than the smallest SGBM band (16 px) is not worth a word
    narrow = reference.copy()
    narrow[:, : adapt.UNCHECKED_COLUMNS - 1] = np.nan
    near = adapt.FitCheck.combine([adapt.check_frame(estimate, narrow, pixels, disparities)])
    assert near.first_column == adapt.UNCHECKED_COLUMNS - 1
    assert "columns" not in near.describe()


def test_a_feature_stream_s_left_out_check_says_no_columns() -> None:
    """Review 57c F3: the left-out check (a feature stream, no SGBM band) took its leftmost
    left-out point's column: "on left-out measurements in columns >= 42" when no point lies
    within 40 px of the border. Before: first_column 40+ and the suffix."""
    rng = np.random.default_rng(3)
    height, width = SIZE
    pixels = np.column_stack([rng.uniform(40, width - 1, 60), rng.uniform(0, height - 1, 60)])
    disparities = 5.0 + pixels[:, 0] / width
    kept, left_out = adapt.left_out_split(60)
    estimate = np.full(SIZE, 5.5, dtype=np.float32)
    check = adapt.FitCheck.combine(
        [adapt.check_left_out(estimate, pixels, disparities, kept, left_out)]
    )
    assert check.frames == 1
    assert check.first_column == 0
    assert "columns" not in check.describe("left-out measurements")


def test_a_check_where_linear_interpolation_is_exact_gives_no_ratio() -> None:
    # every measurement at one disparity: linear's error ~1e-14 px gave "235620346868027.09x"
    pixels = _points(40, seed=1)
    disparities = np.full(40, 12.0)
    kept, left_out = adapt.left_out_split(40)
    estimate = np.full(SIZE, 14.0, dtype=np.float32)
    frame = adapt.check_left_out(estimate, pixels, disparities, kept, left_out)
    check = adapt.FitCheck.combine([frame])
    assert check.linear < adapt.EXACT_LINEAR_PX
    assert check.degenerate
    assert not check.fits
    described = check.describe("left-out measurements")
    assert "x linear" not in described
    assert described.startswith(
        "not checked: linear interpolation is exact on left-out measurements ("
    )
    assert described.endswith(
        "px; they are constant or exactly planar), the prior off by 2.00 px (1 frame)"
    )
    assert not adapt.FitCheck(1, 10, 2.0, 0.5, 1.0).degenerate


def test_linear_interpolation_is_scipys_value_for_value() -> None:
    from scipy.interpolate import LinearNDInterpolator

    rng = np.random.default_rng(3)
    lattice = np.stack(np.meshgrid(np.arange(0, 400, 40.0), np.arange(0, 200, 40.0)), -1)
    for trial in range(40):
        points = rng.random((int(rng.integers(3, 300)), 2)) * [400, 200]
        if trial % 2:  # lattice points: co-circular fours, ties in the triangulation
            grid = lattice.reshape(-1, 2)
            points = np.concatenate([grid[rng.random(len(grid)) < 0.6], points[:20]])
        points = points.astype(np.float32).astype(np.float64)
        values = rng.random(len(points)) * 50
        at = np.stack([rng.integers(-5, 405, 2000), rng.integers(-5, 205, 2000)], 1)
        at = at.astype(np.float64)
        expected = LinearNDInterpolator(points, values)(at)
        np.testing.assert_array_equal(adapt._linear_at(points, values, at), expected)


def test_held_out_pixels_score_every_map_as_the_check_does() -> None:
    reference = _scene(4.0)
    pixels = _points(40, seed=2)
    disparities = _measure(reference, pixels)
    held_out = adapt.HeldOut.of(reference, pixels, disparities)
    for estimate in (reference, np.full(SIZE, 10.0, dtype=np.float32)):
        assert held_out.score(estimate) == adapt.check_frame(
            estimate, reference, pixels, disparities
        )


def test_pixels_below_the_smallest_resolvable_disparity_are_scored_as_written() -> None:
    """Bug hunt 16D F8: the output writes an estimate below its min_disparity as too far
    (depth +inf, disparity 0 read back); the check scored the disparity before that cut, so
    its line said 0.39 px where the output erred 1.16 px. Before: score took no cut."""
    reference = _scene(4.0)  # 10 .. 18.7 px
    pixels = _points(40, seed=1)
    disparities = _measure(reference, pixels)
    held_out = adapt.HeldOut.of(reference, pixels, disparities)
    estimate = reference.copy()
    estimate[:, :20] = 0.5  # far off, and below the cut of 1 px: written as 0
    truth = held_out.truth
    columns = held_out.flat % SIZE[1]
    cut = columns < 20
    as_estimated = held_out.score(estimate)
    assert as_estimated.far == 0
    assert as_estimated.prior == pytest.approx(np.abs(truth[cut] - 0.5).sum() / truth.size)
    written = held_out.score(estimate, min_disparity=1.0)
    assert written.far == cut.sum() > 0
    assert written.cut == 1.0
    assert written.prior == pytest.approx(truth[cut].sum() / truth.size)
    assert (written.linear, written.nearest) == (as_estimated.linear, as_estimated.nearest)
    assert written == adapt.check_frame(estimate, reference, pixels, disparities, 1.0)
    # the pooled check says what share was cut, once it is noticeable
    pooled = adapt.FitCheck.combine([written, written])
    assert pooled.far == 2 * written.far
    share = 100 * cut.mean()
    assert f"; {share:.0f} % of them written as too far and scored so: below 1 px" in (
        pooled.describe()
    )
    assert "too far" not in adapt.FitCheck.combine([as_estimated]).describe()
    few = adapt.FitCheck(1, 1000, 1.0, 1.0, 1.0, far=49, cut=2.0)
    assert "too far" not in few.describe()
    assert "too far" in dataclasses.replace(few, far=50).describe()
    # a feature stream's left-out check cuts as well
    kept, left_out = adapt.left_out_split(40)
    low = np.full(SIZE, 0.5, dtype=np.float32)
    frame = adapt.check_left_out(low, pixels, disparities, kept, left_out, 1.0)
    assert frame.far == left_out.size
    assert frame.prior == pytest.approx(np.abs(disparities[left_out]).mean())


def test_own_basis_from_the_log_reproduces_its_scenes() -> None:
    maps = [adapt.grid_map(_scene(shift), SIZE) for shift in (0.0, 2.0, 4.0, 6.0)]
    basis = adapt.own_basis(maps, SIZE, 50.0)
    assert basis.image_size == SIZE
    assert basis.focal_baseline == 50.0
    assert basis.n_components == 1  # the scenes differ by one scaled step: one direction
    single = adapt.own_basis(maps[:1], SIZE, 50.0)
    assert single.n_components == 1
    np.testing.assert_array_equal(single.mean, maps[0])
    with pytest.raises(ValueError, match="at least one map"):
        adapt.own_basis([], SIZE, 50.0)
    # a static pair repeated (an image publisher, a driver re-sending its last frame)
    repeated = adapt.own_basis([maps[1]] * 3, SIZE, 50.0)
    assert repeated.n_components == 1
    np.testing.assert_array_equal(repeated.mean, maps[1])
    assert len(repeated.fingerprint) == 16


def test_leave_one_out_beats_linear_on_scenes_like_the_others() -> None:
    shifts = (0.0, 2.0, 4.0, 6.0, 8.0)
    references = [_scene(shift) for shift in shifts]
    frames = []
    for index, reference in enumerate(references):
        pixels = _points(30, seed=10 + index)
        frames.append(adapt.Measured(pixels, _measure(reference, pixels), reference))
    maps = [adapt.grid_map(reference, SIZE) for reference in references]
    basis = adapt.refit_prior(adapt.own_basis(maps, SIZE, 50.0), frames, robust="cauchy")
    assert "sigma" in basis.meta["prior"]
    held = adapt.leave_one_out(
        maps, frames, basis.meta["prior"], image_size=SIZE, focal_baseline=50.0, robust="cauchy"
    )
    assert held is not None
    assert held.check.frames == 4
    assert held.check.ratio < 1.0
    assert held.std_scale is None  # not asked for


def test_own_basis_std_is_calibrated_on_frames_it_did_not_learn() -> None:
    # each scene has a bump of its own: a basis of all five maps reproduces each (so a std
    # calibrated on them fits maps it has seen), one learned without a frame cannot
    rows, cols = np.mgrid[0 : SIZE[0], 0 : SIZE[1]].astype(np.float32)
    rng = np.random.default_rng(5)
    frames, maps = [], []
    for index in range(5):
        y, x = rng.uniform(8, SIZE[0] - 8), rng.uniform(8, SIZE[1] - 8)
        bump = 4.0 * np.exp(-((rows - y) ** 2 + (cols - x) ** 2) / 40.0)
        reference = (_scene(2.0 * index) + bump).astype(np.float32)
        pixels = _points(30, seed=20 + index)
        frames.append(adapt.Measured(pixels, _measure(reference, pixels), reference))
        maps.append(adapt.grid_map(reference, SIZE))
    in_sample = adapt.refit_prior(adapt.own_basis(maps, SIZE, 50.0), frames, robust="cauchy")
    prior = in_sample.meta["prior"]
    held = adapt.leave_one_out(
        maps, frames, prior, image_size=SIZE, focal_baseline=50.0, robust="cauchy", calibrate=True
    )
    assert held is not None
    assert held.std_scale is not None
    assert held.check.frames == 4
    assert held.std_scale > 1.5 * prior["std_scale"]


def test_evidence_fits_the_prior_scale_instead_of_a_huge_noise() -> None:
    # measurements drawn from a prior 400x wider than the model's: noise-only evidence
    # can only call them noise; with the scale free the fit finds the prior too narrow
    rng = np.random.default_rng(3)
    factor = rng.normal(size=(60, 6))
    signal = factor @ factor.T + 0.5 * np.eye(60)
    draw = np.linalg.cholesky(400.0 * signal + 0.25 * np.eye(60)) @ rng.normal(size=60)
    assert evidence_sigma(signal, draw) > 5.0
    sigma, scale = evidence_noise(signal, draw)
    assert 100.0 <= scale <= 1600.0
    assert sigma < 5.0
    # the carried points' known noise: fitted on the others
    extra = np.zeros(60)
    extra[:10] = 4.0
    sigma_extra, scale_extra = evidence_noise(signal, draw, extra)
    assert 100.0 <= scale_extra <= 1600.0
    assert np.isfinite(sigma_extra)


def test_leave_one_out_leaves_the_neighbours_out_too() -> None:
    # frames come in near-identical pairs (a bump of their own each pair): a basis that
    # learned a frame's twin reproduces it, so a frame left out alone is scored too well
    rows, cols = np.mgrid[0 : SIZE[0], 0 : SIZE[1]].astype(np.float32)
    rng = np.random.default_rng(7)
    centres = [(rng.uniform(8, SIZE[0] - 8), rng.uniform(8, SIZE[1] - 8)) for _ in range(4)]
    frames, maps = [], []
    for index in range(8):
        y, x = centres[index // 2]
        bump = 4.0 * np.exp(-((rows - y) ** 2 + (cols - x) ** 2) / 40.0)
        reference = (_scene(float(index)) + bump).astype(np.float32)
        pixels = _points(30, seed=40 + index)
        frames.append(adapt.Measured(pixels, _measure(reference, pixels), reference))
        maps.append(adapt.grid_map(reference, SIZE))
    prior = adapt.refit_prior(adapt.own_basis(maps, SIZE, 50.0), frames, robust="cauchy")
    options = {"image_size": SIZE, "focal_baseline": 50.0, "robust": "cauchy"}
    alone = adapt.leave_one_out(maps, frames, prior.meta["prior"], gap=0, **options)
    held = adapt.leave_one_out(maps, frames, prior.meta["prior"], **options)
    assert alone is not None
    assert held is not None
    assert adapt.LEAVE_OUT_GAP >= 1
    assert held.check.frames == alone.check.frames == 4
    assert held.check.prior > 1.8 * alone.check.prior
    # a short warm-up: too few maps beyond the gap, so the frame alone is left out
    short = adapt.leave_one_out(maps[:4], frames[:4], prior.meta["prior"], **options)
    plain = adapt.leave_one_out(maps[:4], frames[:4], prior.meta["prior"], gap=0, **options)
    assert short is not None
    assert plain is not None
    assert short.check == plain.check


def _bumped(centre: tuple[float, float], shift: float) -> np.ndarray:
    rows, cols = np.mgrid[0 : SIZE[0], 0 : SIZE[1]].astype(np.float32)
    bump = 4.0 * np.exp(-((rows - centre[0]) ** 2 + (cols - centre[1]) ** 2) / 40.0)
    return (_scene(shift) + bump).astype(np.float32)


def test_repeated_views_are_labelled_one_view() -> None:
    rng = np.random.default_rng(11)
    still = adapt.grid_map(_bumped((20.0, 20.0), 2.0), SIZE)
    moved = adapt.grid_map(_bumped((30.0, 40.0), 5.0), SIZE)

    def noisy(grid: np.ndarray) -> np.ndarray:  # SGBM's noise on a standing camera
        return (grid + rng.normal(0.0, 0.03, grid.shape)).astype(np.float32)

    maps = [noisy(still), noisy(still), noisy(moved), noisy(still), noisy(moved)]
    assert adapt.view_labels(maps).tolist() == [0, 0, 1, 0, 1]
    assert adapt.view_labels(maps, tolerance=0.0).tolist() == [0, 1, 2, 3, 4]
    # a few cells that change (a person walking past a robot standing) keep the view
    passer = noisy(still)
    passer[:3, :3] += 10.0
    assert adapt.view_labels([maps[0], passer]).tolist() == [0, 0]
    assert adapt.view_labels([]).size == 0


def test_leave_one_out_never_learns_copies_of_the_left_out_view() -> None:
    # a camera standing still for 6 frames, then 2 frames of views of their own: a basis that
    # learned the copies of a left-out standing frame reproduced it (the figure that made a
    # KITTI drive adapt to a basis learned from its standing start)
    rng = np.random.default_rng(12)
    references = [_bumped((20.0, 20.0), 2.0)] * 6
    references += [_bumped((30.0, 44.0), 6.0), _bumped((12.0, 50.0), 9.0)]
    frames, maps = [], []
    for index, reference in enumerate(references):
        noisy = (reference + rng.normal(0.0, 0.03, reference.shape)).astype(np.float32)
        pixels = _points(30, seed=60 + index)
        frames.append(adapt.Measured(pixels, _measure(noisy, pixels), noisy))
        maps.append(adapt.grid_map(noisy, SIZE))
    prior = adapt.refit_prior(adapt.own_basis(maps, SIZE, 50.0), frames, robust="cauchy")
    options = {"image_size": SIZE, "focal_baseline": 50.0, "robust": "cauchy"}
    held = adapt.leave_one_out(maps, frames, prior.meta["prior"], **options)
    assert held is not None
    assert held.check.frames == 3  # one frame per view
    # the first frame left out: learned from the other views only, or (every frame its own
    # view, what the check did before) from the standing frames beyond the gap too
    first = adapt.leave_one_out(maps, frames, prior.meta["prior"], max_frames=1, **options)
    copies = adapt.leave_one_out(
        maps, frames, prior.meta["prior"], max_frames=1, tolerance=0.0, **options
    )
    assert first is not None
    assert copies is not None
    assert first.check.frames == copies.check.frames == 1
    assert first.check.prior > 3.0 * copies.check.prior  # 0.69 against 0.15 px
    # all frames one view: nothing is left to check the log's own basis on
    still = adapt.leave_one_out(maps[:6], frames[:6], prior.meta["prior"], **options)
    assert still is None


def test_maps_the_ego_motion_says_are_one_view_are_one_view() -> None:
    """Fresh sensor noise in every frame puts a standing camera's maps 0.07-0.10 px apart,
    around adapt.SAME_VIEW: the maps alone split them into views, which the log's own basis
    then learned and was checked on as if the camera had moved (``same_as``: the ego-motion's
    word, from pipeline.adaptation.still_links)."""
    rng = np.random.default_rng(13)
    still = adapt.grid_map(_bumped((20.0, 20.0), 2.0), SIZE)
    moved = adapt.grid_map(_bumped((30.0, 40.0), 5.0), SIZE)

    def noisy(grid: np.ndarray) -> np.ndarray:  # median |difference| of two: ~0.14 px
        return (grid + rng.normal(0.0, 0.15, grid.shape)).astype(np.float32)

    maps = [noisy(still), noisy(still), noisy(still), noisy(moved)]
    assert adapt.view_labels(maps).tolist() == [0, 1, 2, 3]
    views = adapt.view_labels(maps, same_as=[0, 0, 1, 3])
    assert views.tolist() == [0, 0, 0, 1]
    # the left-out check: one frame per view, never learning a map of its view
    frames = []
    for index, grid in enumerate(maps):
        reference = np.kron(grid, np.ones((4, 4), np.float32))[: SIZE[0], : SIZE[1]]
        pixels = _points(30, seed=80 + index)
        frames.append(adapt.Measured(pixels, _measure(reference, pixels), reference))
    options = {"image_size": SIZE, "focal_baseline": 50.0, "robust": "cauchy"}
    held = adapt.leave_one_out(maps, frames, {}, views=views, **options)
    assert held is not None
    assert held.check.frames == 2
    assert adapt.leave_one_out(maps[:3], frames[:3], {}, views=views[:3], **options) is None


def _builtin_options(kind: str) -> dict[str, object]:
    return resolve_settings(builtin_basis(kind), ProcessorConfig()).densify_options()


def _rough_measured(count: int) -> list[adapt.Measured]:
    frames = []
    for index in range(count):
        reference = _scene(3.0 * index)
        pixels = _points(40, seed=40 + index)
        frames.append(adapt.Measured(pixels, _measure(reference, pixels), reference))
    return frames


def test_the_indoor_basis_is_tried_with_the_rougher_kernel() -> None:
    """bughunt10B Q3: the indoor basis chosen at >= 0.8x linear is scored with the rougher
    kernel and taken when its held-out error is lower, its std scale refitted on the
    warm-up's SGBM maps. review58b R6: the kernel is a constant (Laplace 64 px, 40 px^2 in
    the indoor basis's px), not the street basis's meta (a refit of it changes nothing);
    R7: the scale is fitted per frame (``scale_by_innovation``, the indoor basis's rule)."""
    street, indoor = builtin_basis("street"), builtin_basis("indoor")
    indoor_options = _builtin_options("indoor")
    against = adapt.FitCheck(2, 1000, 2.49, 2.25, 2.38)
    seen: list[dict[str, object]] = []

    def score(options: dict[str, object]) -> adapt.FitCheck:
        seen.append(options)
        return adapt.FitCheck(2, 1000, 2.35, 2.25, 2.38)

    frames = _rough_measured(3)
    rough = rougher.try_rougher(
        street,  # review58c C7: the basis alone (its options were never read since R6)
        (indoor, "the built-in indoor basis", indoor_options),
        score,
        against,
        (frames, SIZE, 50.0),
        robust="cauchy",
        calibrate=True,
    )
    assert rough is not None
    kernel = LocalPrior(40.0, 64.0, "laplace")
    assert adapt.ROUGH_KERNEL == kernel
    assert seen == [{**indoor_options, "local_prior": kernel}]
    assert rough.tuned is not None
    assert rough.tuned["local_prior"] == kernel
    assert rough.tuned["scale_by_innovation"] is True
    scale = rough.tuned["std_scale"]
    assert isinstance(scale, float)
    options = {**indoor_options, "local_prior": kernel}
    fitted = {"image_size": SIZE, "focal_baseline": 50.0, "robust": "cauchy"}
    assert scale == rougher.sgbm_std_scale(indoor, frames, options, **fitted)  # type: ignore[arg-type]
    plain = rougher.sgbm_std_scale(indoor, frames, options, per_frame=False, **fitted)  # type: ignore[arg-type]
    assert scale != plain
    # R7: at least the Gaussian likelihood's scale (heavy tails), never below the band's
    band = rougher.sgbm_std_scale(indoor, frames, options, likelihood=False, **fitted)  # type: ignore[arg-type]
    assert scale >= band
    assert rough.line == (
        "prior: the built-in indoor basis with the street basis's local kernel (laplace, "
        f"64 px, 40 px^2) {rough.check.describe()}; taken: 2.35 px against 2.49 with its own "
        f"kernel on the same held-out SGBM pixels; its std scale x{scale:.2f}, refitted on the "
        "warm-up's SGBM maps"
    )


def test_the_street_kernel_is_not_taken_when_it_does_no_better() -> None:

    street, indoor = builtin_basis("street"), builtin_basis("indoor")
    given = street
    chosen = (indoor, "the built-in indoor basis", _builtin_options("indoor"))
    against = adapt.FitCheck(8, 1000, 0.3701, 0.50, 1.13)

    def worse(options: dict[str, object]) -> adapt.FitCheck:
        return adapt.FitCheck(8, 1000, 0.3749, 0.50, 1.13)

    rough = rougher.try_rougher(
        given, chosen, worse, against, ([], SIZE, 50.0), robust="cauchy", calibrate=True
    )
    assert rough is not None
    assert rough.tuned is None
    assert rough.line.endswith(
        "; not taken: 0.3749 px against 0.3701 with its own kernel on the same held-out SGBM pixels"
    )
    # no candidate: a basis of the user's (not the built-in street one) or no local kernel
    user = adapt.with_prior(street, dict(street.meta["prior"]))
    assert (
        rougher.try_rougher(
            user,
            chosen,
            worse,
            against,
            ([], SIZE, 50.0),
            robust="cauchy",
            calibrate=True,
        )
        is None
    )
    paper = (indoor, "the built-in indoor basis", {**chosen[2], "local_prior": None})
    assert (
        rougher.try_rougher(
            given, paper, worse, against, ([], SIZE, 50.0), robust="cauchy", calibrate=True
        )
        is None
    )
    # review58c C7: nor an indoor basis whose kernel is already the rougher one
    rough_already = (
        indoor,
        "the built-in indoor basis",
        {**chosen[2], "local_prior": adapt.ROUGH_KERNEL},
    )
    assert (
        rougher.try_rougher(
            given, rough_already, worse, against, ([], SIZE, 50.0), robust="cauchy", calibrate=True
        )
        is None
    )


def test_the_street_kernel_is_not_tried_where_sgbm_left_a_band_unchecked() -> None:
    """A check that covers columns >= 129 only (SGBM at half resolution leaves its left band
    empty): the rougher kernel would extrapolate there unchecked (synthetic rooms at 376x240:
    up to 2.25x the indoor kernel's error in the band, its std holding 21 % of the truth)."""
    given = builtin_basis("street")
    chosen = (builtin_basis("indoor"), "the built-in indoor basis", _builtin_options("indoor"))
    banded = adapt.FitCheck(8, 1000, 0.26, 0.31, 0.45, first_column=129)

    def never(options: dict[str, object]) -> adapt.FitCheck:
        raise AssertionError("scored")

    rough = rougher.try_rougher(
        given, chosen, never, banded, ([], SIZE, 50.0), robust="cauchy", calibrate=True
    )
    assert rough is not None
    assert rough.tuned is None
    assert rough.line == (
        "prior: the built-in indoor basis with the street basis's local kernel (laplace, 64 px, "
        "40 px^2): not tried: the held-out pixels cover columns >= 129 only, and left of them "
        "(SGBM's unmatched band), unchecked, it erred up to 2.2x more than the basis's own "
        "kernel on synthetic rooms"
    )
