"""Learned policies beside the model-based controllers (guide: docs/policies.md): the benchmark as a Gymnasium
environment (``env``: ``BipedPush-v0``, ``BipedRandomPush-v0``; ``spec`` its observation and action vectors;
``pushes`` its push options and random pushes) and policies as controllers (``controller``: a network held
over its policy period behind the controller interface, ``onnx_policy`` an ONNX file run by onnxruntime;
``catalog`` the committed policies under ``policies/<name>/``, each a controller by its name; ``vector`` the
environments vectorised over processes, a batch per worker). Pure Python, no ROS.

Importing this package registers the environments with Gymnasium (Gymnasium 1.x has no plug-in entry
points): ``import biped_controller.policy`` then ``gymnasium.make("BipedPush-v0")``, or, without the import,
``gymnasium.make("biped_controller.policy:BipedPush-v0")``. ``gymnasium.make_vec(ID, num_envs=16, workers=2)``
gives :class:`~biped_controller.policy.vector.BatchVectorEnv` (the ids' vector entry point; Gymnasium's
``vectorization_mode="sync"`` or ``"async"`` still give its own vector environments).
"""
from __future__ import annotations

import gymnasium as _gym


def _register() -> None:
    from biped_controller.policy.env import ENV_ID, RANDOM_PUSH_ENV_ID, load_env_config
    steps = int(load_env_config().max_episode_steps)
    if ENV_ID not in _gym.registry:
        _gym.register(id=ENV_ID, entry_point="biped_controller.policy.env:BipedPushEnv", max_episode_steps=steps,
                      vector_entry_point="biped_controller.policy.vector:make_push_vector")
    if RANDOM_PUSH_ENV_ID not in _gym.registry:
        _gym.register(id=RANDOM_PUSH_ENV_ID, entry_point="biped_controller.policy.env:make_random_push_env",
                      max_episode_steps=steps,
                      vector_entry_point="biped_controller.policy.vector:make_random_push_vector")


_register()
