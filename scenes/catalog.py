"""Descriptions of the built-in rooms (the source of ``scenes/<name>/``).

``scripts/build_scenes.py`` writes each description with
:func:`rfmitsuba.sim.scene_builder.write_scene`; edit a room here, then run the
script and commit the XML and meshes with it. Furniture stands 1 cm off the
walls so that no face of it is coplanar with a wall face.

Materials (ITU-R P.2040 types of Sionna RT): concrete, brick or plasterboard
walls; concrete floor and ceiling slabs; a wooden door; a glass window; wood
furniture; ``carpet_tile`` for mattresses and cushions (ITU lists no foam or
textile; carpet tile is the nearest soft furnishing); metal appliances.
"""
from __future__ import annotations

from rfmitsuba.sim.scene_builder import (
    Material,
    Opening,
    RoomDescription,
    bed,
    block,
    chair,
    shelf,
    sofa,
    table,
)

G = 0.01  # gap between furniture and walls, metres


def _materials(wall_id: str, wall_type: str, wall_thickness: float) -> list[Material]:
    return [
        Material(wall_id, wall_type, wall_thickness),
        Material("slab_concrete", "concrete", 0.2),
        Material("door_wood", "wood", 0.04),
        Material("window_glass", "glass", 0.01),
        Material("furniture_wood", "wood", 0.02),
        Material("soft_textile", "carpet_tile", 0.05),
        Material("appliance_metal", "metal", 0.002),
    ]


def bedroom() -> RoomDescription:
    """4.4 x 3.5 x 2.8 m: bed, nightstand, wardrobe, desk and chair, metal radiator, concrete walls."""
    lx, ly, lz = 4.4, 3.5, 2.8
    return RoomDescription(
        name="bedroom", size=(lx, ly, lz), wall_thickness=0.2,
        materials=_materials("wall_concrete", "concrete", 0.2),
        wall_material="wall_concrete", floor_material="slab_concrete", ceiling_material="slab_concrete",
        openings=[
            Opening("door", "south", offset=0.3, width=0.9, height=2.05, material="door_wood"),
            Opening("window", "north", offset=2.6, width=1.2, height=1.2, sill=0.9,
                    material="window_glass", panel_thickness=0.01),
        ],
        furniture=[
            # bed with its headboard against the east wall
            bed("bed", "furniture_wood", "soft_textile", origin=(lx - G, G), size=(1.6, 2.0), yaw_deg=90.0),
            block("nightstand", "furniture_wood", origin=(lx - G - 0.4, 1.65), size=(0.4, 0.45, 0.55)),
            block("wardrobe", "furniture_wood", origin=(G, 0.9), size=(0.6, 1.2, 2.1)),
            table("desk", "furniture_wood", origin=(0.8, ly - G - 0.6), size=(1.2, 0.6, 0.75)),
            chair("chair", "furniture_wood", origin=(1.65, ly - G - 0.7), yaw_deg=180.0),
            block("radiator", "appliance_metal", origin=(lx - G - 0.1, 2.35), size=(0.1, 1.0, 0.6), z=0.15),
        ],
    )


def living_room() -> RoomDescription:
    """4.3 x 3.5 x 2.8 m: sofa, coffee table, TV stand with a metal TV, bookshelf, brick walls."""
    lx, ly, lz = 4.3, 3.5, 2.8
    return RoomDescription(
        name="living_room", size=(lx, ly, lz), wall_thickness=0.2,
        materials=_materials("wall_brick", "brick", 0.2),
        wall_material="wall_brick", floor_material="slab_concrete", ceiling_material="slab_concrete",
        openings=[
            Opening("door", "west", offset=0.2, width=0.9, height=2.05, material="door_wood"),
            Opening("window", "south", offset=1.6, width=1.5, height=1.3, sill=0.8,
                    material="window_glass", panel_thickness=0.01),
        ],
        furniture=[
            sofa("sofa", "furniture_wood", "soft_textile", origin=(1.2, ly - G - 0.9), size=(2.0, 0.9)),
            table("coffee_table", "furniture_wood", origin=(1.6, 1.45), size=(1.1, 0.6, 0.45)),
            block("tv_stand", "furniture_wood", origin=(1.45, G), size=(1.4, 0.4, 0.5)),
            block("tv", "appliance_metal", origin=(1.6, G + 0.15), size=(1.1, 0.06, 0.65), z=0.5),
            shelf("bookshelf", "furniture_wood", origin=(lx - G - 0.35, 0.9), size=(0.35, 1.0, 1.9),
                  yaw_deg=0.0),
        ],
    )


def dining_room() -> RoomDescription:
    """4.5 x 3.8 x 2.8 m: table with four chairs, sideboard, metal fridge, plasterboard walls."""
    lx, ly, lz = 4.5, 3.8, 2.8
    tx, ty, tw, td = 1.6, 1.4, 1.4, 0.9          # table low corner and size
    return RoomDescription(
        name="dining_room", size=(lx, ly, lz), wall_thickness=0.12,
        materials=_materials("wall_plasterboard", "plasterboard", 0.12),
        wall_material="wall_plasterboard", floor_material="slab_concrete", ceiling_material="slab_concrete",
        openings=[
            Opening("door", "east", offset=2.6, width=0.9, height=2.05, material="door_wood"),
            Opening("window", "north", offset=1.5, width=1.5, height=1.3, sill=0.9,
                    material="window_glass", panel_thickness=0.01),
        ],
        furniture=[
            table("table", "furniture_wood", origin=(tx, ty), size=(tw, td, 0.75)),
            # two chairs on each long side, backs away from the table
            chair("chair_1", "furniture_wood", origin=(tx + 0.15, ty - 0.6)),
            chair("chair_2", "furniture_wood", origin=(tx + 0.8, ty - 0.6)),
            chair("chair_3", "furniture_wood", origin=(tx + 0.6, ty + td + 0.6), yaw_deg=180.0),
            chair("chair_4", "furniture_wood", origin=(tx + 1.25, ty + td + 0.6), yaw_deg=180.0),
            block("sideboard", "furniture_wood", origin=(G, 1.0), size=(0.45, 1.6, 0.85)),
            block("fridge", "appliance_metal", origin=(lx - G - 0.65, G), size=(0.65, 0.65, 1.85)),
        ],
    )


def large_room() -> RoomDescription:
    """11 x 7.5 x 2.8 m open-plan room: lounge, dining and office groups, shelves, a metal cabinet."""
    lx, ly, lz = 11.0, 7.5, 2.8
    return RoomDescription(
        name="large_room", size=(lx, ly, lz), wall_thickness=0.25,
        materials=_materials("wall_concrete", "concrete", 0.25),
        wall_material="wall_concrete", floor_material="slab_concrete", ceiling_material="slab_concrete",
        wall_materials={"north": "wall_concrete"},
        openings=[
            Opening("door", "south", offset=5.0, width=1.0, height=2.1, material="door_wood"),
            Opening("window_north", "north", offset=2.0, width=2.0, height=1.4, sill=0.8,
                    material="window_glass", panel_thickness=0.01),
            Opening("window_east", "east", offset=2.5, width=1.8, height=1.4, sill=0.8,
                    material="window_glass", panel_thickness=0.01),
        ],
        furniture=[
            # lounge (west)
            sofa("sofa", "furniture_wood", "soft_textile", origin=(1.0, ly - G - 0.9), size=(2.2, 0.9)),
            table("coffee_table", "furniture_wood", origin=(1.5, 5.0), size=(1.2, 0.6, 0.45)),
            block("tv_stand", "furniture_wood", origin=(1.3, 3.2), size=(1.6, 0.4, 0.5)),
            block("tv", "appliance_metal", origin=(1.5, 3.35), size=(1.2, 0.06, 0.7), z=0.5),
            shelf("bookshelf", "furniture_wood", origin=(G, 1.0), size=(0.35, 1.2, 2.0)),
            # dining (centre)
            table("dining_table", "furniture_wood", origin=(5.0, 3.2), size=(1.6, 0.9, 0.75)),
            chair("chair_1", "furniture_wood", origin=(5.2, 2.6)),
            chair("chair_2", "furniture_wood", origin=(5.95, 2.6)),
            chair("chair_3", "furniture_wood", origin=(5.65, 4.7), yaw_deg=180.0),
            chair("chair_4", "furniture_wood", origin=(6.4, 4.7), yaw_deg=180.0),
            block("sideboard", "furniture_wood", origin=(4.8, ly - G - 0.45), size=(1.8, 0.45, 0.85)),
            # office (east)
            table("desk_1", "furniture_wood", origin=(8.3, G), size=(1.4, 0.7, 0.75)),
            chair("office_chair_1", "furniture_wood", origin=(9.25, 1.3), yaw_deg=180.0),
            table("desk_2", "furniture_wood", origin=(8.3, 5.2), size=(1.4, 0.7, 0.75)),
            chair("office_chair_2", "furniture_wood", origin=(8.55, 4.55)),
            block("metal_cabinet", "appliance_metal", origin=(lx - G - 0.5, 0.2), size=(0.5, 1.0, 1.9)),
            block("plant_stand", "furniture_wood", origin=(10.3, ly - G - 0.5), size=(0.5, 0.5, 0.9)),
        ],
    )


#: name -> description factory, in the order :func:`rfmitsuba.scenes.available` lists them.
ROOMS = {"bedroom": bedroom, "living_room": living_room, "dining_room": dining_room, "large_room": large_room}
