"""The mapper's forward-motion retry: a plate none of whose pairs can start COLMAP's model (driving footage)."""

from types import SimpleNamespace

import pytest

from camcal.pipelines.solve_colmap import (REFINED_GLOBAL_BA_RATIO, REFINED_GLOBAL_BA_REFINEMENTS,
                                          REFINED_LOCAL_BA_REFINEMENTS, SEQUENTIAL_INIT_TRI_ANGLE_DEG, map_images)


class _Model:
    def __init__(self, registered):
        self.registered = registered

    def num_reg_images(self):
        return self.registered


class _Database:
    def num_images(self):
        return 51

    def close(self):
        pass


def _pycolmap(calls, registered_by_forward):
    """A stand-in for pycolmap's incremental mapper: the registered images depend on the first-pair bound
    ``init_max_forward_motion`` (COLMAP's default 0.95 refuses a pair moving along its view), each run recorded
    with the folder it writes to."""
    def incremental_mapping(database, image_dir, sparse, options):
        forward = options.mapper.init_max_forward_motion
        calls.append((forward, sparse.name))
        (sparse / "0").mkdir()
        return {0: _Model(registered_by_forward[forward])} if registered_by_forward[forward] else {}

    def pipeline_options():
        return SimpleNamespace(mapper=SimpleNamespace(init_max_forward_motion=0.95))

    return SimpleNamespace(set_random_seed=lambda seed: None, IncrementalPipelineOptions=pipeline_options,
                           incremental_mapping=incremental_mapping,
                           Database=SimpleNamespace(open=lambda path: _Database()))


@pytest.mark.parametrize("first, forward, kept", [(0, 51, 51), (20, 51, 51), (30, 12, 30), (51, 0, 51)])
def test_the_mapper_retries_with_a_forward_first_pair_and_keeps_the_run_that_registers_more(tmp_path, first, forward,
                                                                                           kept):
    calls = []
    sparse = tmp_path / "sparse"
    sparse.mkdir()
    models, note = map_images(_pycolmap(calls, {0.95: first, 1.0: forward}), tmp_path / "db", tmp_path, sparse,
                              "incremental", 0, hold_intrinsics=True)
    assert max((m.num_reg_images() for m in models.values()), default=0) == kept
    if first == 51:  # every image registered: one run, nothing said
        assert calls == [(0.95, "sparse")] and note == ""
        return
    assert calls == [(0.95, "sparse"), (1.0, "sparse.forward")]
    assert note.startswith(f"the mapper registered {first} of 51 images; started again from a pair that may move "
                           f"along its view (forward motion): {forward}")
    assert note.endswith(", kept" if forward > first else ", the first run kept")
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith("sparse")) == ["sparse"]


@pytest.mark.parametrize("sequential, refined", [(True, True), (True, False), (False, True)])
def test_the_mapper_adjusts_the_whole_model_less_often_only_on_a_plate_camcal_refines_afterwards(tmp_path, sequential,
                                                                                                  refined):
    """COLMAP's own growth ratio (1.1) and rounds of global and local adjustment unless the pairs were matched in frame order and camcal's bundle adjustment
    refines the model afterwards; the real pipeline's options object carries both names."""
    import pycolmap

    seen = []

    def incremental_mapping(database, image_dir, sparse, options):
        seen.append((options.ba_global_frames_ratio, options.ba_global_points_ratio, options.ba_global_max_refinements,
                     options.ba_local_max_refinements, options.mapper.init_min_tri_angle))
        return {0: _Model(51)}

    stand_in = SimpleNamespace(set_random_seed=lambda seed: None,
                               IncrementalPipelineOptions=pycolmap.IncrementalPipelineOptions,
                               incremental_mapping=incremental_mapping,
                               Database=SimpleNamespace(open=lambda path: _Database()))
    map_images(stand_in, tmp_path / "db", tmp_path, tmp_path, "incremental", 0, sequential=sequential, refined=refined)
    default = pycolmap.IncrementalPipelineOptions()
    ratio = REFINED_GLOBAL_BA_RATIO if sequential and refined else default.ba_global_frames_ratio
    rounds = REFINED_GLOBAL_BA_REFINEMENTS if sequential and refined else default.ba_global_max_refinements
    local = REFINED_LOCAL_BA_REFINEMENTS if sequential and refined else default.ba_local_max_refinements
    assert seen == [(ratio, ratio, rounds, local,
                     SEQUENTIAL_INIT_TRI_ANGLE_DEG if sequential else default.mapper.init_min_tri_angle)]
    assert REFINED_GLOBAL_BA_RATIO > default.ba_global_frames_ratio == default.ba_global_points_ratio
    assert REFINED_GLOBAL_BA_REFINEMENTS < default.ba_global_max_refinements
    assert REFINED_LOCAL_BA_REFINEMENTS < default.ba_local_max_refinements
