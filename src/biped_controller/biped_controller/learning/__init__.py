"""The learned baseline (issue 42 part 3; guide docs/policies_training.md): PPO trained on the Gymnasium
environment ``BipedRandomPush-v0`` (``policy.env``) and exported as an ONNX policy (``policy.catalog``).

``mlp``: the trained policy's deterministic action (the Gaussian's mean) as plain NumPy from its weights file;
``onnx_export``: the same network as an ONNX graph built with the ``onnx`` package; ``ppo_config``: the
training settings (``config/training/<name>.yaml``); ``curve``: the training curve's file and its figure.
These four need only the default install. ``ppo_train`` (``scripts/train``) needs the training extra
(``scripts/setup-train``: skrl, JAX) and imports it only when it trains. Pure Python, no ROS.
"""
