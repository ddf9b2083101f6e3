"""The published figures of the paper, by table label: Bian et al., "One Walk is All You Need:
Data-Efficient 3D RF Scene Reconstruction with Human Movements" (preprint; no venue is named).

Numbers are copied from the paper's LaTeX tables (mean / median test SSIM); keys name our
rooms, tasks and methods so that :mod:`rfmitsuba.experiments` can print them beside ours.
Scene 1 = bedroom, Scene 2 = small living room, Scene 3 = dining room (paper Appendix E,
Table ``tab:large_scene_limitations``).
"""
from __future__ import annotations

#: tab:generalization_combined_concise - (room, task, method) -> (mean, median), 900 locations.
MAIN = {
    ("bedroom", "rx", "baseline"): (0.844, 0.886), ("bedroom", "tx", "baseline"): (0.873, 0.906),
    ("bedroom", "rx", "end_to_end"): (0.884, 0.929), ("bedroom", "tx", "end_to_end"): (0.881, 0.924),
    ("bedroom", "rx", "ours"): (0.927, 0.967), ("bedroom", "tx", "ours"): (0.941, 0.975),
    ("living_room", "rx", "baseline"): (0.847, 0.897), ("living_room", "tx", "baseline"): (0.875, 0.897),
    ("living_room", "rx", "end_to_end"): (0.868, 0.894), ("living_room", "tx", "end_to_end"): (0.877, 0.937),
    ("living_room", "rx", "ours"): (0.943, 0.977), ("living_room", "tx", "ours"): (0.898, 0.983),
    ("dining_room", "rx", "baseline"): (0.830, 0.891), ("dining_room", "tx", "baseline"): (0.860, 0.904),
    ("dining_room", "rx", "end_to_end"): (0.821, 0.882), ("dining_room", "tx", "end_to_end"): (0.856, 0.916),
    ("dining_room", "rx", "ours"): (0.862, 0.942), ("dining_room", "tx", "ours"): (0.897, 0.976),
}

#: tab:ablation_strategy - method -> mean SSIM (bedroom, moving RX).
TWO_STAGE = {"end_to_end": 0.858, "continued": 0.844, "ours": 0.927}

#: tab:ablation_info - method -> mean SSIM (bedroom, moving RX).
PERTURBATION = {"baseline": 0.844, "duplicated": 0.761, "baseline_person": 0.895, "ours": 0.927}

#: tab:material_properties - perturber material -> (mean, median) of Ours (bedroom, moving RX).
MATERIAL = {"metal": (0.915, 0.958), "concrete": (0.935, 0.972), "tissue": (0.927, 0.967)}

#: tab:large_scene_limitations - room -> (Baseline, Ours test, Ours val) mean SSIM.
LARGE_ROOM = {"bedroom": (0.844, 0.927, 0.920), "living_room": (0.847, 0.943, 0.936),
              "dining_room": (0.830, 0.883, 0.862), "large_room": (0.866, 0.731, 0.928)}

#: tab:motivation - number of RX locations (empty room, Baseline) -> (mean, median).
POSITIONS = {900: (0.844, 0.886), 1500: (0.859, 0.904), 3600: (0.911, 0.947), 6000: (0.920, 0.949),
             10000: (0.929, 0.952)}

#: tab:style_adapted_comparison - (model, data, room) -> (mean, median); "wrfgsplus_mod" is
#: the paper's Baseline, person-present = our "baseline_person".
DATA_AUGMENTATION = {
    ("wrfgsplus_mod", "empty", "bedroom"): (0.844, 0.886), ("wrfgsplus_mod", "person", "bedroom"): (0.895, 0.937),
    ("wrfgsplus_mod", "empty", "living_room"): (0.847, 0.897),
    ("wrfgsplus_mod", "person", "living_room"): (0.918, 0.954),
    ("wrfgsplus_mod", "empty", "dining_room"): (0.830, 0.891),
    ("wrfgsplus_mod", "person", "dining_room"): (0.852, 0.924),
}

#: Room labels of the paper.
ROOM_LABELS = {"bedroom": "Scene 1 (bedroom)", "living_room": "Scene 2 (living room)",
               "dining_room": "Scene 3 (dining room)", "large_room": "Larger scene (11 x 7.5 m)"}
