"""Seed 001's RQRLP landing pattern (systems/perception/rqrlp/): its geometry and its texture."""

import numpy as np
import pytest

from systems.config import ConfigError
from systems.perception.rqrlp.nodes import location_markers
from systems.perception.rqrlp.pattern import MARKERS, RqrlpLayout, rqrlp_image, rqrlp_texture_name, texture_blocks

LAYOUT = RqrlpLayout()


def pixel(image, layout, p):
    """The image's value at the point p (x, y) of P [m]."""
    scale = layout.pixels / layout.size_m
    return image[int((layout.size_m / 2 - p[1]) * scale), int((p[0] + layout.size_m / 2) * scale)]


def test_the_texture_shows_the_layouts_markers_and_outline():
    image = rqrlp_image(LAYOUT)
    assert image.shape == (LAYOUT.pixels, LAYOUT.pixels) and image.dtype == np.uint8
    for marker in MARKERS:
        outer, middle, inner = LAYOUT.marker_corners_P(marker)
        centre = LAYOUT.marker_centres_P[marker]
        assert pixel(image, LAYOUT, centre) == 0  # the inner black square
        ring = (middle[0, :2] + inner[0, :2]) / 2
        assert pixel(image, LAYOUT, ring) == 255  # the white square between
        assert pixel(image, LAYOUT, (outer[0, :2] + middle[0, :2]) / 2) == 0  # the outer black
    edge = LAYOUT.size_m / 2 - LAYOUT.border_m / 2
    assert pixel(image, LAYOUT, [0.0, edge]) == 0 and pixel(image, LAYOUT, [edge, 0.1]) == 0
    # The texture: corner-rich, never as dark as the markers, so only they nest three contours deep.
    middle = slice(LAYOUT.pixels // 2 - 100, LAYOUT.pixels // 2 + 100)
    inside = image[middle, middle]
    assert inside.min() > 50 and len(np.unique(inside)) >= 4
    assert np.array_equal(image, rqrlp_image(LAYOUT))  # the same pattern every time


def test_the_texture_draws_the_border_and_each_square_to_the_layouts_pixels():
    """Measured in the image, the border on each side spans texture_px(border_m), and each marker's three
    squares start and end (along its centre row and column) at their corners' positions in texture pixels:
    the image's runs of black and white change exactly there, a whole pixel of the texture to each."""
    image = rqrlp_image(LAYOUT)
    n, half = LAYOUT.pixels, LAYOUT.size_m / 2
    border = LAYOUT.texture_px(LAYOUT.border_m)
    assert border == round(border) and border > 0
    for line in (image[n // 2], image[n // 2, ::-1], image[:, n // 2], image[::-1, n // 2]):  # from each side
        assert np.argmax(line != 0) == border  # the texture inside is never black
    for marker in MARKERS:
        squares = LAYOUT.marker_corners_P(marker)
        centre = LAYOUT.marker_centres_P[marker]
        cols = [LAYOUT.texture_px(x + half) for x in (*squares[:, 0, 0], *squares[::-1, 2, 0])]
        rows = [LAYOUT.texture_px(half - y) for y in (*squares[:, 0, 1], *squares[::-1, 2, 1])]
        row, col = round(LAYOUT.texture_px(half - centre[1])), round(LAYOUT.texture_px(centre[0] + half))
        for line, edges in ((image[row], cols), (image[:, col], rows)):
            start, end = round(edges[0]) - 5, round(edges[-1]) + 5  # from the quiet zone around it
            changes = start + 1 + np.flatnonzero(np.diff(line[start:end].astype(int)) != 0)
            np.testing.assert_array_equal(changes, edges)


def test_top_is_off_the_longest_line_between_the_markers():
    centres = LAYOUT.marker_centres_P
    right_bottom = np.linalg.norm(centres["right"] - centres["bottom"])
    assert right_bottom > np.linalg.norm(centres["top"] - centres["right"])
    assert right_bottom > np.linalg.norm(centres["top"] - centres["bottom"])


def test_nested_squares_have_the_qr_proportions():
    squares = LAYOUT.marker_corners_P("top")
    sides = [np.linalg.norm(s[0] - s[1]) for s in squares]
    np.testing.assert_allclose(np.array(sides) / sides[0], [1.0, 5 / 7, 3 / 7])


@pytest.mark.parametrize("changes", [{"size_m": 0.4}, {"border_m": 0.0}, {"pixels": 100}])
def test_a_layout_that_does_not_fit_is_a_config_error(changes):
    with pytest.raises(ConfigError, match="platform.rqrlp"):
        RqrlpLayout(**changes).validate()


@pytest.mark.parametrize("changes, named", [
    ({"border_m": 0.0002}, "border_m"),  # rounded to no border, and image[-0:] painted the whole pattern black
    ({"margin_m": 0.0009}, "margin_m"),  # no white around the markers: the texture runs into them
    ({"marker_m": 0.0063}, "marker_m"),  # 1.8 px modules: rounding closes the rings, no marker is found
    ({"texture_cell_m": 0.0004}, "texture_cell_m"),
    ({"texture_cell_m": 0.13}, "texture_cell_m"),  # no 4-cell block drawn
])
def test_a_layout_the_texture_cannot_draw_is_a_config_error(changes, named):
    with pytest.raises(ConfigError, match=rf"platform\.rqrlp\.{named} \(.*\) is too"):
        RqrlpLayout(**changes).validate()


def test_the_smallest_layout_the_texture_draws_shows_its_markers_and_border():
    """A pixel of border and of quiet zone, 2 px modules, 1 px cells: the markers are found in the texture,
    the border is black and the inside is not."""
    pixel = LAYOUT.size_m / LAYOUT.pixels
    layout = RqrlpLayout(border_m=pixel, margin_m=2 * pixel, marker_m=14 * pixel, texture_cell_m=pixel)
    layout.validate()
    image = rqrlp_image(layout)
    assert len(location_markers(image)) == 3
    n = layout.pixels
    assert not image[[0, n - 1], :].any() and not image[:, [0, n - 1]].any()
    assert image[1:n - 1, 1:n - 1].min() == 0 and np.mean(image[1:n - 1, 1:n - 1] == 0) < 0.01


@pytest.mark.parametrize("size_m, pixels", [(0.85, 1700), (0.5, 856), (1.0, 2100)])
def test_a_layout_of_whole_texture_pixels_is_valid(size_m, pixels):
    """A border, quiet zone and texture cell of one texture pixel (size_m / pixels) and a module of two, the
    least `validate` allows: valid, however the floats round (0.5 / 856 * 856 / 0.5 = 1 - 1e-16)."""
    pixel = size_m / pixels
    layout = RqrlpLayout(size_m=size_m, pixels=pixels, border_m=pixel, margin_m=2 * pixel, marker_m=14 * pixel,
                         texture_cell_m=pixel)
    layout.validate()
    assert layout.texture_px(pixel) == 1.0 and layout.texture_px(2 * pixel) == 2.0


def test_the_outline_corners_are_half_the_size_from_the_centre():
    """The default 0.85 m pattern's outer corners at +-0.425 m, in marker_corners_P's order (top-left,
    bottom-left, bottom-right, top-right)."""
    expected = 0.425 * np.array([[-1, 1, 0], [-1, -1, 0], [1, -1, 0], [1, 1, 0]])
    np.testing.assert_allclose(LAYOUT.outline_corners_P, expected, rtol=0, atol=1e-15)


@pytest.mark.parametrize("marker_m, fits", [(0.25, False), (0.24, True)])
def test_location_markers_that_touch_do_not_fit(marker_m, fits):
    """A 1 m pattern, 12.5 cm of border and of margin: two 25 cm markers side by side span 1 - 2 (0.125 + 0.125)
    = 0.5 m, exactly the room between the margins: they touch, and do not fit (every other check passes: 250 px
    of border, 71 px modules, 20 px cells, 80 px blocks). 24 cm markers leave a gap and fit."""
    layout = RqrlpLayout(size_m=1.0, border_m=0.125, margin_m=0.125, marker_m=marker_m, pixels=2000)
    if fits:
        layout.validate()
    else:
        with pytest.raises(ConfigError, match="do not fit"):
            layout.validate()


@pytest.mark.parametrize("pixels, valid", [(256, True), (255, False)])
def test_the_texture_needs_256_pixels_at_least(pixels, valid):
    layout = RqrlpLayout(pixels=pixels)
    if valid:
        layout.validate()
    else:
        with pytest.raises(ConfigError, match=r"platform\.rqrlp\.pixels must be at least 256"):
            layout.validate()


def test_a_texture_of_a_single_largest_block_is_valid():
    """10 cm texture cells on the default 1700 px texture: a 4-cell block is 40 cm, 800 px a side, and
    int((1700 / 800)^2 * 0.35) = int(1.58) = 1 of them is drawn: one is enough."""
    layout = RqrlpLayout(texture_cell_m=0.1)
    assert texture_blocks(layout)[0] == (800, 1)
    layout.validate()


def test_the_texture_name_changes_with_the_texture_seed():
    assert rqrlp_texture_name(RqrlpLayout(texture_seed=1)) != rqrlp_texture_name(RqrlpLayout(texture_seed=2))
