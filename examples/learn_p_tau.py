"""Learn the T-conorm parameter p and the scale τ jointly from a target silhouette.

The target is rendered with yager(p=3), τ = 0.03 (logistic coverage); the fit starts at p = 1,
τ = 0.1 and recovers both by Adam on the mean squared error of the alpha channel. p and τ are
parametrized to stay in their domains (p = softplus(a) > 0, τ = exp(b) > 0): a p that left the
domain would raise gendr.ParameterError at the next render.

    python examples/learn_p_tau.py [--backend torch|drjit] [--steps 200]
"""
import argparse

import numpy as np
import torch

import gendr
from gendr.scenes import icosphere


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--backend", default="torch")
    ap.add_argument("--steps", type=int, default=200)
    args = ap.parse_args()

    mesh = icosphere(1)
    verts = torch.as_tensor(mesh.vertices * np.array([1.0, 0.7, 0.8]))  # float64
    cam = gendr.orbit_camera(30.0, 20.0, 3.0, fov_y=40.0)
    size = (32, 32)

    def render(p, tau):
        r = gendr.Renderer("logistic", gendr.tconorm("yager", p=p), tau=tau, image_size=size,
                           backend=args.backend, blend=None)
        return r.render(verts, mesh.faces, cam)[..., 3]

    with torch.no_grad():
        target = render(torch.tensor(3.0, dtype=torch.float64), torch.tensor(0.03, dtype=torch.float64))

    a = torch.tensor(np.log(np.expm1(1.0)), dtype=torch.float64, requires_grad=True)  # p = softplus(a) = 1
    b = torch.tensor(np.log(0.1), dtype=torch.float64, requires_grad=True)             # τ = exp(b) = 0.1
    opt = torch.optim.Adam([a, b], lr=0.1)
    for step in range(args.steps + 1):
        p, tau = torch.nn.functional.softplus(a), torch.exp(b)
        loss = ((render(p, tau) - target) ** 2).mean()
        if step % 40 == 0 or step == args.steps:
            print(f"step {step:3d}  loss {loss.item():.3e}  p {p.item():.4f}  tau {tau.item():.5f}")
        if step == args.steps:
            break
        opt.zero_grad()
        loss.backward()
        opt.step()
    print(f"target: p 3.0000  tau 0.03000")


if __name__ == "__main__":
    main()
