"""Can the Fetch of ``cross_robot``'s test split reach the cube within an episode, and what does the
Panda-learned reward say along the way?

    .venv/bin/python results/families/cross_robot_reuse/fetch_reach.py > results/families/cross_robot_reuse/fetch_reach.txt

1. A scripted controller that moves the TCP straight at the cube (end-effector delta position
   = 10 x the TCP-to-object vector, clipped to [-1, 1]; gripper open; other actions 0), 3 episodes
   per robot: the TCP-to-object distance and the first discriminator's logit D_0 of the reward
   learned with the Panda (``reward_panda_283k.pt``) every 5 steps.
2. One action dimension of the Fetch held at +1 (or -1) for 10 steps from the start: how far the
   TCP moves (world x, y, z).
3. The best scripted Fetch approach found: the arm down first, then at the cube, with the base
   driving forward.
"""

from pathlib import Path

import torch

from drs_torchrl.envs import make_family_env
from drs_torchrl.tasks import get_family
from drs_torchrl.transforms import DrSReward

torch.set_num_threads(1)
HERE = Path(__file__).resolve().parent
REWARD = DrSReward.from_checkpoint(HERE / "reward_panda_283k.pt")
FAMILY = get_family("cross_robot")
TCP, TCP_TO_OBJ = slice(10, 13), slice(13, 16)  # PickObjectEnv.task_observation layout


def task_obs(td):
    return td["task_observation"].reshape(-1)


def d0(td) -> float:
    with torch.no_grad():
        logits = REWARD.discriminators(torch.cat([td[k].float() for k in REWARD.reward_in_keys], -1))
    return float(logits.reshape(-1)[0])


def scripted(env, steps=50, down_first=0, base=0.0):
    td = env.reset()
    dist, logit = [], []
    for t in range(steps):
        a = torch.zeros(env.action_spec.shape)
        if t < down_first:
            a[..., 2] = -1.0
        else:
            a[..., :3] = (task_obs(td)[TCP_TO_OBJ] * 10).clamp(-1, 1)
        a[..., 3] = 1.0
        if base:
            a[..., 7] = base
        td = env.step(td.set("action", a))["next"]
        dist.append(float(task_obs(td)[TCP_TO_OBJ].norm()))
        logit.append(d0(td))
    return dist, logit


def main():
    print("1. straight at the cube, 50 steps (every 5th step shown)")
    for variant in ("panda_cube_2cm", "fetch_cube_2cm"):
        env = make_family_env(FAMILY, variant, seed=1)
        for ep in range(3):
            dist, logit = scripted(env)
            print(f"  {variant} episode {ep}: |TCP - object| m " + " ".join(f"{x:.3f}" for x in dist[4::5]))
            print(f"  {variant} episode {ep}: D_0 logit        " + " ".join(f"{x:6.2f}" for x in logit[4::5]))
        env.close()

    print("2. Fetch: one action dimension held for 10 steps from the start (TCP displacement, world x y z, m)")
    env = make_family_env(FAMILY, "fetch_cube_2cm", seed=1)
    names = {0: "arm x", 1: "arm y", 2: "arm z", 7: "base forward", 8: "base turn"}
    for dim, name in names.items():
        for sign in (1.0, -1.0):
            td = env.reset()
            tcp0 = task_obs(td)[TCP].clone()
            for _ in range(10):
                a = torch.zeros(env.action_spec.shape)
                a[..., dim] = sign
                td = env.step(td.set("action", a))["next"]
            moved = task_obs(td)[TCP] - tcp0
            print(f"  {name:12s} {sign:+.0f}: " + " ".join(f"{v:+.3f}" for v in moved.tolist()))

    print("3. Fetch: arm down for N steps, then at the cube; base forward at +1 (or 0); |TCP - object| every 5th step")
    for down in (5, 10):
        for base in (0.0, 1.0):
            dist, logit = scripted(env, down_first=down, base=base)
            print(
                f"  down {down:2d}, base {base:.0f}: "
                + " ".join(f"{x:.2f}" for x in dist[4::5])
                + f"   D_0 at the end {logit[-1]:.2f}"
            )
    env.close()


if __name__ == "__main__":
    main()
