// Rotation helpers on Eigen with the conventions of conventions.h: DCM/quaternion naming,
// scalar-first exchange, Exp/Log of rotation vectors, skew matrices.
#ifndef ESG_ESTIMATOR_ROTATION_H_
#define ESG_ESTIMATOR_ROTATION_H_

#include <array>

#include "Eigen/Core"
#include "Eigen/Geometry"

namespace esg::estimator {

using Eigen::Matrix3d;
using Eigen::Quaterniond;
using Eigen::Vector3d;

// (q0, q1, q2, q3), scalar first, as in every exchange format.
using ScalarFirst = std::array<double, 4>;

// The only crossings between wire quaternions and Eigen (Eigen #375: constructor order w,x,y,z
// differs from coeffs() storage x,y,z,w). No normalisation is done here.
Quaterniond QuaternionFromScalarFirst(const ScalarFirst& q);
ScalarFirst ToScalarFirst(const Quaterniond& q);

// Sign-canonical form q0 >= 0 (for output edges only).
Quaterniond Canonical(const Quaterniond& q);

// [v]x such that Skew(a) * b == a.cross(b).
Matrix3d Skew(const Vector3d& v);

// Exp(v) = [cos(|v|/2); sin(|v|/2) v/|v|]: rotation by |v| [rad] about v/|v|.
Quaterniond ExpQuaternion(const Vector3d& rotation_vector);
// Inverse of ExpQuaternion, result with |v| <= pi.
Vector3d LogQuaternion(const Quaterniond& q);
// Rotation matrix of a rotation vector (Rodrigues).
Matrix3d ExpMatrix(const Vector3d& rotation_vector);

// Angle [rad] of the rotation q_a * conj(q_b) in [0, pi], insensitive to the sign of either.
double RotationAngle(const Quaterniond& q_a, const Quaterniond& q_b);

// Unit vector perpendicular to u (|u| = 1), deterministic.
Vector3d AnyPerpendicular(const Vector3d& u);

// Re-orthonormalise a near-rotation matrix (SVD projection onto SO(3)).
Matrix3d NearestRotation(const Matrix3d& M);

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_ROTATION_H_
