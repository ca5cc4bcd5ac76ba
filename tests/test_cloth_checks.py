"""check_blown_up: cloth that blew up by strain or distance (with the speed limit on it cannot go
fast) is labelled diverged, on a synthetic track against a brute-force reading of the bounds."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from pipeline.cloth_checks import FAR_MIN, MAX_STRAIN, ClothBlewUp, check_blown_up
from stages.sim import SimulationDiverged

SHEET = np.array([[0.0, 1.0, 0.0], [0.1, 1.0, 0.0], [0.0, 1.0, 0.1], [0.1, 1.0, 0.1]])
TRI = np.array([[0, 1, 2], [1, 3, 2]])
BODY = np.zeros((4, 5, 3)) + np.array([[0.0, 0.0, 0.0], [0.3, 1.7, 0.2], [0.1, 0.5, 0.1], [-0.3, 0.2, -0.2],
                                       [0.0, 1.0, 0.0]])


def _result(frames):
    track = SimpleNamespace(name="sheet", positions=np.stack(frames), triangles=TRI)
    return SimpleNamespace(garments=[track])


def test_a_quiet_sheet_passes():
    assert check_blown_up(_result([SHEET] * 4), BODY, 1.7) is None


def test_an_edge_stretched_past_the_bound_is_diverged_at_its_first_frame():
    stretched = SHEET.copy()
    stretched[3] += [0.1 * (MAX_STRAIN + 1.5), 0.0, 0.0]      # edge 1-3 (0.1 m) becomes ~0.66 m long
    err = check_blown_up(_result([SHEET, SHEET, stretched, stretched]), BODY, 1.7)
    assert isinstance(err, ClothBlewUp) and isinstance(err, SimulationDiverged)
    assert err.frame == 2 and err.garment_names == ("sheet",)
    assert "stretched" in str(err) and "frame 2" in str(err) and "'sheet'" in str(err)
    barely = SHEET.copy()
    barely[3] += [0.1 * (MAX_STRAIN - 0.5) * 0.5, 0.0, 0.0]   # well under the bound
    assert check_blown_up(_result([SHEET, barely, barely, barely]), BODY, 1.7) is None


def test_a_particle_far_from_the_body_is_diverged():
    fallen = SHEET.copy()
    fallen[:, 1] -= 78.0            # the dt: 1 run: 78 m below the floor, at modest strain
    err = check_blown_up(_result([SHEET, SHEET, SHEET, fallen]), BODY, 1.7)
    assert err is not None and err.frame == 3 and "m from the body" in str(err)
    near = SHEET.copy()
    near[:, 1] -= FAR_MIN * 0.5     # under the bound (max(5 m, 5 heights))
    assert check_blown_up(_result([SHEET, near, near, near]), BODY, 1.7) is None


def test_run_keeps_the_recording_of_cloth_that_blew_up_and_names_it(tmp_path, monkeypatch, capsys):
    # a torn garment (a limb dragging a waistband: one edge 602 %) ended in exit 2 and no file to look at
    import pipeline.cloth_checks as checks
    from pipeline.cli import main
    from tests.rrd_read import entity_paths, rows
    monkeypatch.setattr(checks, "MAX_STRAIN", -1.0)        # every frame "blows up": the check is what is tested
    scene = tmp_path / "torn.yaml"      # limb_release: 0 keeps the stop (no second run)
    scene.write_text("character: {clip: rest}\nframes: {count: 3}\noutput: out.rrd\nsimulation: {limb_release: 0}\n"
                     "garments: [{type: rectangle, resolution: [6, 6], width: 0.4, height: 0.4, center: [0, 2, 0]}]\n")
    monkeypatch.chdir(tmp_path)
    assert main(["run", str(scene), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "simulation diverged at frame 0" in err[0] and "out.diverged.rrd" in err[0]
    assert not (tmp_path / "out.rrd").exists()           # the output itself is never a failed run
    kept = tmp_path / "out.diverged.rrd"
    paths = entity_paths(kept)
    assert "/meta/diverged" in paths and "/meta/summary" in paths      # logged to the end
    assert any(p.startswith("/sim/") for p in paths)
    assert len(rows(kept, "sim/rectangle/mesh", "Mesh3D:vertex_positions")) == 3   # every frame simulated


def test_a_torn_run_is_simulated_again_letting_go_and_says_so(tmp_path, monkeypatch, capsys):
    # limb_release left unset: a run whose cloth tore is simulated again with it, with a warning; torn
    # again (here every frame "blows up"), it stops as before
    import pipeline.cloth_checks as checks
    from pipeline.cli import main
    from tests.rrd_read import rows
    monkeypatch.setattr(checks, "MAX_STRAIN", -1.0)
    scene = tmp_path / "torn.yaml"
    scene.write_text("character: {clip: rest}\nframes: {count: 3}\noutput: out.rrd\n"
                     "garments: [{type: rectangle, resolution: [6, 6], width: 0.4, height: 0.4, center: [0, 2, 0]}]\n")
    monkeypatch.chdir(tmp_path)
    assert main(["run", str(scene), "-q"]) == 2
    err = capsys.readouterr().err
    assert "cloth torn at frame 0" in err and "simulated again" in err and "limb_release" in err
    last = err.strip().splitlines()[-1]
    assert "simulation diverged at frame 0" in last and "in a second run too" in last
    # the second run's recording, with the release counted per frame
    assert len(rows(tmp_path / "out.diverged.rrd", "sim/penetrations/released", "Scalars:scalars")) == 3


def test_run_keeps_no_file_for_bad_input(tmp_path, monkeypatch, capsys):
    from pipeline.cli import main
    scene = tmp_path / "bad.yaml"
    scene.write_text("character: {clip: rest}\nframes: {count: 3}\noutput: out.rrd\n"
                     "garments: [{type: mesh, path: missing.obj}]\n")
    monkeypatch.chdir(tmp_path)
    assert main(["run", str(scene), "-q"]) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.yaml"]


def test_an_edge_crushed_at_frame_0_is_judged_against_its_rest_length():
    # sewing left an edge of GarmentCode's dress_s1001 0.07 mm long at frame 0 (rest 23.4 mm): back at
    # its own length it read as stretched 17,955 % against frame 0 and the run stopped as diverged
    crushed = SHEET.copy()
    crushed[3] = crushed[1] + [0.0, 0.0, 0.0001]            # edge 1-3: 0.1 mm at frame 0 (rest 0.1 m)
    frames = [crushed, SHEET, SHEET, SHEET]
    edges = np.array([[0, 1], [0, 2], [1, 2], [1, 3], [2, 3]])
    rest = np.linalg.norm(SHEET[edges[:, 0]] - SHEET[edges[:, 1]], axis=1)
    garment = SimpleNamespace(springs=np.vstack([edges, [[0, 3]]]), rest_lengths=np.append(rest, 0.05),
                              kinds=np.array([0, 0, 0, 0, 0, 1], np.int8))     # 5 stretch, 1 bend
    assert check_blown_up(_result(frames), BODY, 1.7) is not None           # against frame 0 alone
    assert check_blown_up(_result(frames), BODY, 1.7, [garment]) is None
    torn = SHEET.copy()
    torn[3] += [0.1 * (MAX_STRAIN + 1.5), 0.0, 0.0]          # past the bound from its rest length too
    err = check_blown_up(_result([crushed, SHEET, torn, torn]), BODY, 1.7, [garment])
    assert err is not None and err.frame == 2


def test_a_tear_names_the_limb_and_what_lets_it_pass_unless_the_garment_is_worn_round_it(tmp_path):
    # the message of a run stopped by the strain bound says which colliders tore the cloth, and, for a
    # limb the garment is not worn round (a hand through trousers), the ignore_colliders that lets it
    # pass; a sleeve's own arm is never named there (ignoring it, a tee's sleeve fell into the arm:
    # 8 % of its particles inside the body)
    from pipeline.cloth_checks import torn_by
    from stages.rig.humanoid import limb_joint_sets
    from tests.scene_setup import scene_parts
    p = tmp_path / "rest.yaml"
    p.write_text("character: {clip: walk}\nframes: {count: 2, blend_in: 0}\n")
    _, c, m, cols = scene_parts(p)
    arm = limb_joint_sets(c)["arm_l"]

    def depth(j):       # ancestors within the arm
        n = 0
        while c.parents[j] in arm:
            j, n = c.parents[j], n + 1
        return n
    hand = max(arm, key=depth)
    at = lambda f, j: m.joint_world[f][j][:3, 3] + m.root_translation[f]
    edges = np.array([[0, 1], [0, 2], [1, 2], [1, 3], [2, 3]])
    garment = SimpleNamespace(name="sheet", springs=edges, kinds=np.zeros(5, np.int8),
                              rest_lengths=np.linalg.norm(SHEET[edges[:, 0]] - SHEET[edges[:, 1]], axis=1))
    far = SHEET + at(0, c.root_joint) + [0.0, 0.0, 1.0]      # a metre in front of the body: round no limb
    torn = far.copy()
    torn[3] = at(1, hand)                                    # one corner dragged into the hand
    blown = ClothBlewUp(1, "sheet", 3, "has an edge stretched")
    hint = torn_by(blown, [garment], _result([far, torn]), cols, c, m)
    assert hint is not None and "ignore_colliders: [" in hint, hint
    named = hint.split("ignore_colliders: [")[1].split("]")[0].split(", ")
    assert named and set(named) <= {c.joint_names[j] for j in arm}
    ignoring = [tuple(c.joint_names.index(n) for n in named)]   # already in the garment's ignore_colliders
    again = torn_by(blown, [garment], _result([far, torn]), cols, c, m, ignored=ignoring)
    assert again is not None      # still names what touched the torn edge
    suggested = again.split("ignore_colliders: [")[1].split("]")[0].split(", ") if "ignore_colliders: [" in again else []
    assert not set(suggested) & set(named), again
    worn = SHEET - SHEET.mean(axis=0) + at(0, hand)          # at frame 0 on the hand: worn round it
    hint = torn_by(blown, [garment], _result([worn, torn]), cols, c, m)
    assert hint is not None and c.joint_names[hand] in hint.split(":")[0]       # still named as what tore it
    assert "ignore_colliders: [" not in hint or c.joint_names[hand] not in hint.split("ignore_colliders: [")[1].split("]")[0]
