"""The textured quads of models/ (tags, pads, the ground), made on first use and reused from models/generated:
a file is reused only where it is the one the code would make now, not one left by older code."""

from pathlib import Path

import cv2
import numpy as np

import models.apriltag as apriltag
import models.ground_texture as ground_texture
from models.apriltag import source_digest, tag_image, tag_mesh_path, textured_quad_mesh
from models.ground_texture import ground_texture_image, ground_texture_mesh


def read_png(obj: Path) -> np.ndarray:
    return cv2.imread(str(obj.with_suffix(".png")), cv2.IMREAD_UNCHANGED)


def test_a_quad_is_named_by_its_image(tmp_path):
    """Two images under one name are two files, each showing its own image; the same image again is the same file,
    not written again."""
    dark, light = np.full((8, 8), 40, np.uint8), np.full((8, 8), 200, np.uint8)
    first = textured_quad_mesh("plate", dark, tmp_path)
    second = textured_quad_mesh("plate", light, tmp_path)
    assert first != second and first.name.startswith("plate_") and second.name.startswith("plate_")
    np.testing.assert_array_equal(read_png(first), dark)
    np.testing.assert_array_equal(read_png(second), light)
    written = first.stat().st_mtime_ns
    assert textured_quad_mesh("plate", dark.copy(), tmp_path) == first
    assert first.stat().st_mtime_ns == written
    assert textured_quad_mesh("plate", dark.reshape(4, 16), tmp_path) != first  # the same bytes, another shape


def test_a_quad_s_obj_and_mtl_show_its_png(tmp_path):
    """The OBJ names its MTL and material, the MTL the PNG beside it, untinted (Kd 1: the renderer multiplies the
    texture by it)."""
    obj = textured_quad_mesh("plate", np.zeros((8, 8), np.uint8), tmp_path)
    stem = obj.stem
    assert f"mtllib {stem}.mtl" in obj.read_text() and f"usemtl {stem}" in obj.read_text()
    mtl = obj.with_suffix(".mtl").read_text().splitlines()
    assert f"newmtl {stem}" in mtl and f"map_Kd {stem}.png" in mtl and "Kd 1 1 1" in mtl


def test_a_changed_quad_text_makes_new_files(tmp_path, monkeypatch):
    """Code that writes the OBJ or MTL otherwise (here the material's colour) does not reuse the files the old code
    wrote."""
    image = np.zeros((8, 8), np.uint8)
    before = textured_quad_mesh("plate", image, tmp_path)
    quad_files = apriltag._quad_files
    monkeypatch.setattr(apriltag, "_quad_files", lambda stem: {**quad_files(stem), ".mtl": b"Kd 0.5 0.5 0.5\n"})
    after = textured_quad_mesh("plate", image, tmp_path)
    assert after != before and after.with_suffix(".mtl").read_bytes() == b"Kd 0.5 0.5 0.5\n"


def test_each_tag_id_has_its_own_plate():
    """The plates of tags 0 and 1 are two files, each showing its tag (which OpenCV's dictionary detects as that
    id, in the plate's quiet zone)."""
    paths = [tag_mesh_path(tag_id) for tag_id in (0, 1)]
    assert paths[0] != paths[1]
    assert [p.name.split("_")[1] for p in paths] == ["000", "001"]
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11))
    for tag_id, path in zip((0, 1), paths):
        image = read_png(path)
        np.testing.assert_array_equal(image, tag_image(tag_id))
        _, ids, _ = detector.detectMarkers(image)
        assert ids is not None and ids.ravel().tolist() == [tag_id]


def test_source_digest_changes_with_a_file_s_bytes(tmp_path):
    code = tmp_path / "generator.py"
    code.write_text("LEVEL = 1\n")
    first = source_digest(code)
    assert source_digest(code) == first and len(first) == 10
    code.write_text("LEVEL = 2\n")
    assert source_digest(code) != first


def test_a_ground_texture_is_made_again_when_its_code_changes(tmp_path, monkeypatch):
    """The ground is named by its parameters and its code's digest (its image takes seconds to make): a file left by
    other code under the same parameters is not reused."""
    before = ground_texture_mesh(5, 64, 2, 3, tmp_path)
    assert before.name == f"ground_texture_s5_p64_f2_o3_{source_digest(Path(ground_texture.__file__))}.obj"
    monkeypatch.setattr(ground_texture, "source_digest", lambda *paths: "othercode0")
    after = ground_texture_mesh(5, 64, 2, 3, tmp_path)
    assert after.name == "ground_texture_s5_p64_f2_o3_othercode0.obj" and before.exists()
    np.testing.assert_array_equal(read_png(after), ground_texture_image(5, 64, 2, 3))
