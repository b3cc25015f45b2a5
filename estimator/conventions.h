// Frames, rotations, error states and time: the conventions every file of the project follows.
// Written once here; docs/conventions.md repeats them for readers outside the code.
//
// Frames (closed list of tags): `in` inertial (J2000 axes), `b` spacecraft body, `k`/`k1..k4`
// gyro case frame (readout and suspension axes), `int` quasi-inertial frame of a working pair.
//
// 1. DCM. `C_a_b` maps coordinates in `b` to coordinates in `a`: v_a = C_a_b * v_b.
//    Composition cancels adjacent tags: C_a_c = C_a_b * C_b_c. Inverse: C_b_a = C_a_b^T.
// 2. Quaternion. `q_a_b` is the unit quaternion of C_a_b, Hamilton convention, scalar first
//    (q0, q1, q2, q3) in every exchange format: v_a = q_a_b (x) v_b (x) conj(q_a_b), and
//    q_a_b.toRotationMatrix() == C_a_b. In memory Eigen::Quaterniond; crossing to and from
//    scalar-first arrays goes only through rotation.h (QuaternionFromScalarFirst, ToScalarFirst);
//    Eigen's (w,x,y,z) constructor order differs from its (x,y,z,w) coeffs() storage.
//    The paper's attitude quaternion L_in,c is q_in_b.
// 3. Sign. q and -q are one attitude; canonicalised to q0 >= 0 only at output edges.
// 4. Pinning example. If b is in turned +90 deg about in's z axis, then b's x axis points along
//    in's y axis: C_in_b * (1,0,0) = (0,1,0) and q_in_b = (cos 45deg, 0, 0, sin 45deg).
// 5. Attitude error. q_in_b(true) = Exp(dtheta_in) (x) q_in_b(est), with
//    Exp(v) = [cos(|v|/2); sin(|v|/2) v/|v|]. dtheta_in is a small rotation in inertial axes.
//    Spin-axis error: h_in(true) = h_in(est) + dh_in, dh_in perpendicular to h_in; its components
//    in `int` axes are the paper's dh_int1_1, dh_int3_1 (reference gyro) and dh_int1_2,
//    dh_int2_2 (second gyro).
// 6. Quasi-inertial frame of a working pair (reference gyro a, second gyro b), from predicted
//    inertial spin axes: e2 = h_a, e1 = unit(h_a x h_b), e3 = e1 x e2; rows of C_int_in are
//    e1, e2, e3. Then h_b = cos(theta) e2 + sin(theta) e3.
// 7. Drift. dw_k is the drift angular velocity of the spin axis in case axes [rad/s]; the axis
//    moves as dh_in/dt = (C_in_k dw_k) x h_in (docs/physics.md, "Drift model").
// 8. Units. SI inside (s, rad, rad/s) with no suffix; non-SI names carry a suffix from the
//    closed list _deg, _deg_h, _arcsec, _arcmin, _mv, _um, _hours, _min (units.h converts).
// 9. Time. Instants are absl::Time in UTC, RFC 3339 with `Z` at the edges. absl::Time has no
//    leap seconds: a recording that spans a UTC leap second is off by 1 s across it (the time
//    scale is UTC without leap-second smearing, an explicit decision).
#ifndef ESG_ESTIMATOR_CONVENTIONS_H_
#define ESG_ESTIMATOR_CONVENTIONS_H_

namespace esg::estimator {

inline constexpr int kMaxGyros = 4;
// Gyro ids are 1..kMaxGyros; index = id - 1.

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_CONVENTIONS_H_
