"""A user's sensor model through relmap's filter and calibration: a 360° camera's angles."""

import dataclasses

import numpy as np

import relmap as rm
from relmap.filter.autocalibration import calibrate


@dataclasses.dataclass(frozen=True)
class Panorama(rm.models.Measurement):  # landmarks (x, y, height); numeric Jacobians (the base's)
    sigma: float = 0.01  # rad, z = h(x, l) + v with v ~ N(0, σ² I)
    dim, angles, landmark_dim, noise_parameters = 2, (0,), 3, ("sigma",)

    def h(self, x, lm=None):  # bearing and elevation of lm from a camera 1 m above the pose x
        p = (lm[..., 0] - x[..., 0] + 1j * (lm[..., 1] - x[..., 1])) * np.exp(-1j * x[..., 2])
        return np.stack([np.angle(p), np.arctan2(lm[..., 2] - 1.0, np.abs(p))], -1)

    def noise(self, z):
        return np.multiply.outer(np.square(self.sigma) + np.zeros(np.shape(z)[:-1]), np.eye(2))


lm, x0 = rm.sim.random_landmarks(5, 8, (-6, -6, 1.5), (6, 6, 3)), rm.AT([-2.0, 0.0, 0.0])
truth = rm.models.Odometry(rm.models.DistanceNoise(0.01, 0.01, 0.002)), Panorama(0.02)
guess = rm.models.Odometry(rm.models.DistanceNoise(0.05, 0.05, 0.01)), Panorama(0.1)
sim = rm.sim.simulate(rm.sim.Patrol([[2, 0], [-2, 0]]), *truth, lm, start=x0, steps=300, seed=1)
paired = rm.filter.run(sim.log(), *truth, lm, start=x0, associate="mahalanobis").landmark
cal = calibrate(sim.recording(), *guess, lm, start=lambda t: x0, associate="mahalanobis")
print(f"paired right {np.mean(paired == sim.landmark):.1%}", cal.motion.noise, cal.sensor, sep="\n")
