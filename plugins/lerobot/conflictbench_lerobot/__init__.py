"""Any LeRobot policy for conflictbench, played the way ``lerobot-eval --env.type=libero`` plays it."""
