"""Which camera-IMU rotation a drive's ground truth and its gyro agree on, beside the file's.

    .venv/bin/python benchmarks/rotation_truth.py [FILE.npz] [--model MODEL.toml]

Hand-eye rotation from the ground truth alone (no vision): over each interval the ground
truth's camera rotation increment ``C_k``, moved into IMU axes by a candidate ``cam_R_imu``,
should equal the gyro's ``exp(tau_k w_k)`` under the velocity pairing; the candidate that
minimises the rms of their difference is printed against the file's (a rotation vector in IMU
axes, mrad), with the residual rms at both, for each pairing, and the residual at the rotation
of ``--model`` (for example a cached identified model's .toml). Default: kitti-utias 0027.
"""
import argparse
import numpy as np
from scipy.spatial.transform import Rotation as Rot
from scipy.optimize import least_squares
from vislam.eval.groundtruth import read_kitti_poses, orthonormalise
from vislam.ekf.model import Model
from vislam.eval.groundtruth import ground_truth_path

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument('file', nargs='?', default='../shared/data/kitti-utias/0027.npz')
parser.add_argument('--model')
args = parser.parse_args()
d = np.load(args.file)
P,_ = read_kitti_poses(ground_truth_path(args.file)); P = orthonormalise(P)
w = d['rotational_velocity'].T; tau = np.diff(d['time_stamps'].ravel())
Rf = d['cam_T_imu'][:3,:3]
C = np.linalg.inv(P[:-1]) @ P[1:]; Cr = C[:, :3, :3]
n = len(Cr)
for pairing in ['current','next','mean']:
    u = {'current': w[:n], 'next': w[1:n+1], 'mean': 0.5*(w[:n]+w[1:n+1])}[pairing]
    G = Rot.from_rotvec(u*tau[:n,None]).as_matrix()
    def res(x, R0):
        R = Rot.from_rotvec(x).as_matrix() @ R0   # cam_R_imu candidate
        Rimu = np.einsum('ji,njk,kl->nil', R, Cr, R)
        return Rot.from_matrix(np.einsum('nji,njk->nik', G, Rimu)).as_rotvec().ravel()
    sol = least_squares(res, np.zeros(3), args=(Rf,))
    dimu = Rf.T @ Rot.from_rotvec(sol.x).as_matrix() @ Rf
    print(pairing, 'best cam_R_imu vs file (imu axes, mrad):', (Rot.from_matrix(dimu).as_rotvec()*1e3).round(2), 'rms resid mrad', (np.sqrt(np.mean(sol.fun**2))*1e3).round(3), 'at file', (np.sqrt(np.mean(res(np.zeros(3),Rf)**2))*1e3).round(3))
if args.model:
    m = Model.from_toml(args.model)
    Ri = np.array(m.cam_T_imu)[:3,:3]
    u = w[1:n+1]; G = Rot.from_rotvec(u*tau[:n,None]).as_matrix()
    Rimu = np.einsum('ji,njk,kl->nil', Ri, Cr, Ri)
    print('at the model rotation, next: rms resid mrad', (np.sqrt(np.mean(Rot.from_matrix(np.einsum('nji,njk->nik', G, Rimu)).as_rotvec()**2))*1e3).round(3))
print('total yaw of drive (deg)', np.degrees(np.sum(w[:n,2]*tau[:n])).round(1))
