import sys, numpy as np, sgdr.backend as b; b.init('llvm')
from sgdr.synth import mpm
n_grid=24; dx=1/n_grid
s = dx/4**(1/3)
g = np.arange(0.4, 0.6, s)+s/2
x = np.stack(np.meshgrid(g,g,g,indexing='ij'),-1).reshape(-1,3)
E,nu,rho=float(sys.argv[1]),0.3,1e3
sub = mpm.cfl_substeps(1/24, dx, E, nu, rho, 0.3, 3.0)
gz = 0.2 + 0.37*dx
model = mpm.create_model(x, s**3, rho, n_grid, dx, (0,0,gz-4*dx), 1/24/sub, 'neo_hookean', sys.argv[2], 0.5, (0,0,gz),(0,0,1))
params = mpm.MPMParams.create(E,nu,(0,0,-9.8))
st = mpm.MPMState.at_rest(x,(0.3,0,0))
fr, st = mpm.simulate(model, params, st, 40, sub)
print('sub', sub, 'min z - ground [dx]', ((fr[:, :, 2].min(1)-gz)/dx).round(2))
print('com x', fr[:, :, 0].mean(1).round(3))
