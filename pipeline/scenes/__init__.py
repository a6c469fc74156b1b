"""The world an episode observes: scenes (boxes, views, meshes), procedural objects and the ground-truth
renderer; ``python -m pipeline.scenes show SCENE`` draws one."""
