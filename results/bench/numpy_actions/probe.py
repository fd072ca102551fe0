import time, numpy as np, torch, gymnasium as gym
import mani_skill.envs  # noqa
torch.set_num_threads(1)
env = gym.make("PickCube-v1", obs_mode="state", control_mode="pd_ee_delta_pos", num_envs=1, sim_backend="physx_cpu", reward_mode="sparse", render_mode=None)
env.reset(seed=0)
def run(kind, n=400):
    t=time.perf_counter()
    for _ in range(n):
        a = env.action_space.sample()
        if kind == "torch": a = torch.as_tensor(a).unsqueeze(0)
        elif kind == "torch_flat": a = torch.as_tensor(a)
        _,_,te,tr,_ = env.step(a)
        if bool((te|tr).any()): env.reset()
    return n/(time.perf_counter()-t)
res={"numpy":[], "torch":[]}
for r in range(4):
    for k in res: res[k].append(run(k))
for k,v in res.items(): print(k, [round(x) for x in v], "median", round(float(np.median(v))))
