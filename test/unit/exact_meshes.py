"""The exact check the tests hold the sphere body to: the meshes themselves, by python-fcl (the FCL MoveIt uses)
through trimesh's collision manager. Test-only: python-fcl is never imported at run time."""
from __future__ import annotations

import os

import trimesh
from trimesh.collision import CollisionManager

from robot_ai.motion.body import CollisionModel

ROBOTS = os.path.join(os.path.dirname(os.path.realpath(__file__)), '..', '..', '..', 'shared', 'robots')
MESHES = os.path.join(ROBOTS, 'meshes')     # the UR5's and the Panda's real collision meshes (SOURCES.md)


class Exact:
    """The meshes themselves, by python-fcl: one collision manager for the whole body and the world (transforms set
    per configuration), and one per link for distances."""

    def __init__(self, body: CollisionModel):
        self.body = body
        self.world = CollisionManager()
        self.single = {}
        for link in body.links:
            self.world.add_object(link, body.meshes[link])
            self.single[link] = CollisionManager()
            self.single[link].add_object(link, body.meshes[link])
        self.shapes = {}
        for o in body.obstacles:
            shape = trimesh.creation.box(extents=o.size) if o.kind == 'box' else trimesh.creation.icosphere(
                subdivisions=3, radius=o.size[0])
            self.world.add_object(o.name, shape, transform=o.pose)
            self.shapes[o.name] = (shape, o.pose)
        moving = {link for link, m in zip(body.links, body.moving) if m}
        self.pairs = {tuple(sorted((body.links[i], body.links[j]))) for i, j in body.link_pairs}
        self.pairs |= {tuple(sorted((link, o.name))) for link in moving for o in body.obstacles}

    def contacts(self, poses: dict, n: int) -> set:
        """The checked pairs whose meshes touch in configuration n."""
        for link in self.body.links:
            self.world.set_transform(link, poses[link][n])
        _, names = self.world.in_collision_internal(return_names=True)
        return {tuple(sorted(pair)) for pair in names} & self.pairs

    def distance(self, poses: dict, n: int, a: str, b: str) -> float:
        self.single[a].set_transform(a, poses[a][n])
        shape, pose = self.shapes[b] if b in self.shapes else (self.body.meshes[b], poses[b][n])
        return self.single[a].min_distance_single(shape, transform=pose)

    def contacts_along(self, poses: dict, count: int) -> list[tuple[int, list]]:
        """(configuration, pairs) for every configuration of poses ({link: (count, 4, 4)}) whose meshes touch in a
        checked pair or with an obstacle."""
        return [(n, sorted(touching)) for n in range(count) if (touching := self.contacts(poses, n))]
