"""``osms/Catch-v0`` for LeRobot's ``lerobot-eval``: an ``EnvConfig`` registered as ``osms``.

    lerobot-eval --env.discover_packages_path=osms --env.type=osms \\
        --env.conditions=dev --policy.path=PATH --eval.n_episodes=50 --eval.batch_size=10 \\
        --seed=0 --output_dir=out/lerobot-eval

LeRobot seeds episode ``k`` of an evaluation with ``seed + k``, and the environment runs
condition ``(seed + k) mod n`` of the set, so ``--seed=0 --eval.n_episodes=N`` evaluates the
set's first N conditions, each under osms's own protocol. The policy sees ``agent_pos`` as
``observation.state`` (the deployable frame, the same 76 channels as the LeRobot export's
``observation.state``) and answers 24 actions in [-1, 1]. LeRobot 0.5 and later build the
environments through ``create_envs``, which here makes osms's native vector environment
(:class:`osms.gym.CatchVectorEnv`, stepped in Rust) in LeRobot's SAME_STEP autoreset mode;
LeRobot 0.4 vectorises ``osms/Catch-v0`` itself. Without this config, LeRobot's ``eval_policy``
runs on ``gymnasium.make_vec("osms/Catch-v0", num_envs=n, vectorization_mode=
"vector_entry_point")`` as it is (``scripts/check-lerobot-eval`` does both). Importing this
module needs LeRobot; the rest of the package does not.
"""

from dataclasses import dataclass, field

from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig
from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_STATE

import osms  # noqa: F401  (registers osms/Catch-v0 with gymnasium)
from osms._native import DEFAULT_CONTROL_HZ, DEPLOYABLE_LEN, N_ACTION, PRIVILEGED_LEN
from osms._project import project as _project
from osms._project import protocol as _protocol


@EnvConfig.register_subclass("osms")
@dataclass
class OsmsEnv(EnvConfig):
    """The catching world under an osms evaluation protocol (see the module's doc)."""

    task: str | None = "Catch-v0"
    fps: int = int(round(DEFAULT_CONTROL_HZ))
    conditions: str = "dev"
    protocol: str | None = None
    profile: str | None = None
    privileged: bool = False
    # lerobot-eval writes videos of the first episodes from rendered frames.
    render_mode: str | None = "rgb_array"
    features: dict[str, PolicyFeature] = field(
        default_factory=lambda: {
            ACTION: PolicyFeature(type=FeatureType.ACTION, shape=(N_ACTION,)),
            "agent_pos": PolicyFeature(type=FeatureType.STATE, shape=(DEPLOYABLE_LEN,)),
        }
    )
    features_map: dict[str, str] = field(
        default_factory=lambda: {
            ACTION: ACTION,
            "agent_pos": OBS_STATE,
            "environment_state": OBS_ENV_STATE,
        }
    )

    def __post_init__(self):
        if self.privileged:
            self.features["environment_state"] = PolicyFeature(type=FeatureType.ENV, shape=(PRIVILEGED_LEN,))

    @property
    def package_name(self) -> str:
        return "osms"

    @property
    def gym_id(self) -> str:
        return f"osms/{self.task}"

    def create_envs(self, n_envs: int, use_async_envs: bool = False):
        """One native vector environment (LeRobot >= 0.5 calls this; ``use_async_envs`` has
        nothing to add: the sub-environments already step in parallel in Rust)."""
        from gymnasium.vector import AutoresetMode

        from osms.gym import CatchVectorEnv

        env = CatchVectorEnv(n_envs, autoreset_mode=AutoresetMode.SAME_STEP, **self.gym_kwargs)
        return {self.type: {0: env}}

    @property
    def gym_kwargs(self) -> dict:
        proto = _protocol(_project(profile=self.profile), self.conditions, self.protocol)
        return {
            "conditions": self.conditions,
            "protocol": self.protocol,
            "profile": self.profile,
            "privileged": self.privileged,
            "render_mode": self.render_mode,
            # The world ends every episode by its rules within this many steps; LeRobot reads it.
            "max_episode_steps": proto.max_steps,
        }
