"""World readings -> ROS messages (REP-103 SI units, REP-105 frames), one function each.

6x6 covariances are row-major over (x, y, z, roll, pitch, yaw) for poses and
(vx, vy, vz, wx, wy, wz) for twists. Components the planar simulator does not measure
get ``UNMEASURED_VARIANCE`` on the diagonal (never 0 or -1, which consumers could fuse).
"""

from __future__ import annotations

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseWithCovarianceStamped, Quaternion
from nav_msgs.msg import Odometry
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image, Imu, JointState

from ekf_localization.core.angles import matrix_to_rpy, rpy_to_quaternion, yaw_to_quaternion
from ekf_localization.core.units import ns_to_sec_nanosec
from ekf_localization.vision.pinhole import PinholeCamera
from sim_robot.world.camera_image_sensor import ImageReading
from sim_robot.world.camera_sensor import CameraReading
from sim_robot.world.dead_wheel_sensor import DeadWheelReading
from sim_robot.world.imu_sensor import ImuReading
from sim_robot.world.wheel_encoder_sensor import WheelEncoderReading
from sim_robot.world.world import TruthReading

UNMEASURED_VARIANCE = 1e6
STANDARD_GRAVITY = 9.80665  # m/s², REP-145: accelerometers report +g on z when level
_PLANAR = (0, 1, 5)  # x, y, yaw rows/columns of a 6x6 covariance


def stamp(t_ns: int) -> Time:
    """Integer nanoseconds -> builtin_interfaces/Time (no float seconds)."""
    sec, nanosec = ns_to_sec_nanosec(t_ns)
    return Time(sec=sec, nanosec=nanosec)


def clock(t_ns: int) -> Clock:
    return Clock(clock=stamp(t_ns))


def orientation(q: tuple[float, float, float, float]) -> Quaternion:
    """geometry_msgs/Quaternion of an (x, y, z, w) from ``core.angles`` (which does the maths)."""
    x, y, z, w = q
    return Quaternion(x=x, y=y, z=z, w=w)


def planar_covariance(cov3: np.ndarray | None) -> list[float]:
    """A 6x6 covariance (flattened) from a 3x3 one over (x, y, yaw); unmeasured rows large."""
    C = np.diag(np.full(6, UNMEASURED_VARIANCE))
    if cov3 is not None:
        C[np.ix_(_PLANAR, _PLANAR)] = cov3
    return [float(c) for c in C.ravel()]


def dead_wheel_odometry(r: DeadWheelReading, t_ns: int, frame: str, child: str, i: int = 0) -> Odometry:
    msg = Odometry()
    msg.header.stamp = stamp(t_ns)
    msg.header.frame_id = frame
    msg.child_frame_id = child
    tw = r.twist[i]
    msg.twist.twist.linear.x = float(tw[0])
    msg.twist.twist.linear.y = float(tw[1])
    msg.twist.twist.angular.z = float(tw[2])
    msg.twist.covariance = planar_covariance(r.twist_cov[i])
    if r.pose is not None and r.pose_cov is not None:
        msg.pose.pose.position.x = float(r.pose[i, 0])
        msg.pose.pose.position.y = float(r.pose[i, 1])
        msg.pose.pose.orientation = orientation(yaw_to_quaternion(float(r.pose[i, 2])))
        msg.pose.covariance = planar_covariance(r.pose_cov[i])
    else:
        msg.pose.pose.orientation.w = 1.0
        msg.pose.covariance = planar_covariance(None)
    return msg


def joint_states(r: DeadWheelReading, t_ns: int, names: tuple[str, ...], wheel_radius: float,
                 i: int = 0) -> JointState:
    """The dead wheels as ros2_control's joint_state_broadcaster reports them: positions in rad
    (accumulated distance along the surface / wheel radius), no velocities, no frame."""
    msg = JointState()
    msg.header.stamp = stamp(t_ns)
    msg.name = list(names)
    msg.position = [float(d) / wheel_radius for d in r.distances[i]]
    return msg


def wheel_joint_states(r: WheelEncoderReading, t_ns: int, names: tuple[str, ...], i: int = 0) -> JointState:
    """The drive's wheels as joint_state_broadcaster reports a motor driver's encoders: positions in
    rad (whole counts), velocities in rad/s, no frame; a swerve's drive joints then its steer joints
    (angle in rad, rate in rad/s), ``names`` in that order."""
    msg = JointState()
    msg.header.stamp = stamp(t_ns)
    msg.name = list(names)
    positions, velocities = r.positions[i], r.velocities[i]
    if r.steer_angles is not None and r.steer_rates is not None:
        positions = np.concatenate([positions, r.steer_angles[i]])
        velocities = np.concatenate([velocities, r.steer_rates[i]])
    msg.position = [float(p) for p in positions]
    msg.velocity = [float(w) for w in velocities]
    return msg


def camera_pose(r: CameraReading, t_ns: int, frame: str, i: int = 0) -> PoseWithCovarianceStamped:
    msg = PoseWithCovarianceStamped()
    msg.header.stamp = stamp(t_ns)
    msg.header.frame_id = frame
    msg.pose.pose.position.x = float(r.pose[i, 0])
    msg.pose.pose.position.y = float(r.pose[i, 1])
    msg.pose.pose.orientation = orientation(yaw_to_quaternion(float(r.pose[i, 2])))
    msg.pose.covariance = planar_covariance(r.cov[i])
    return msg


def imu(r: ImuReading, t_ns: int, frame: str, i: int = 0) -> Imu:
    msg = Imu()
    msg.header.stamp = stamp(t_ns)
    msg.header.frame_id = frame
    big = UNMEASURED_VARIANCE
    if r.tilt is None:
        msg.orientation = orientation(yaw_to_quaternion(float(r.yaw[i])))
        msg.orientation_covariance = [big, 0.0, 0.0, 0.0, big, 0.0, 0.0, 0.0, float(r.yaw_variance)]
    else:  # roll and pitch: the tilt on the field surface (a ramp), REP-145 fixed axes
        msg.orientation = orientation(rpy_to_quaternion(float(r.tilt[i, 0]), float(r.tilt[i, 1]),
                                                        float(r.yaw[i])))
        tv = float(r.tilt_variance)
        msg.orientation_covariance = [tv, 0.0, 0.0, 0.0, tv, 0.0, 0.0, 0.0, float(r.yaw_variance)]
    msg.angular_velocity.z = float(r.yaw_rate[i])
    msg.angular_velocity_covariance = [big, 0.0, 0.0, 0.0, big, 0.0, 0.0, 0.0, float(r.yaw_rate_variance)]
    msg.linear_acceleration.x = float(r.accel[i, 0])
    msg.linear_acceleration.y = float(r.accel[i, 1])
    msg.linear_acceleration.z = STANDARD_GRAVITY
    a = float(r.accel_variance)
    msg.linear_acceleration_covariance = [a, 0.0, 0.0, 0.0, a, 0.0, 0.0, 0.0, a]
    return msg


def ground_truth(r: TruthReading, t_ns: int, frame: str, child: str, i: int = 0) -> Odometry:
    """Exact truth: pose in ``frame``, body-frame twist; covariances are zero (no uncertainty)."""
    msg = Odometry()
    msg.header.stamp = stamp(t_ns)
    msg.header.frame_id = frame
    msg.child_frame_id = child
    s = r.truth[i]
    msg.pose.pose.position.x = float(s[0])
    msg.pose.pose.position.y = float(s[1])
    if r.attitude is None:
        msg.pose.pose.orientation = orientation(yaw_to_quaternion(float(s[2])))
    else:  # on a ramp: height and tilt on the surface
        z, roll, pitch = (float(v) for v in r.attitude[i])
        msg.pose.pose.position.z = z
        msg.pose.pose.orientation = orientation(rpy_to_quaternion(roll, pitch, float(s[2])))
    msg.twist.twist.linear.x = float(s[3])
    msg.twist.twist.linear.y = float(s[4])
    msg.twist.twist.angular.z = float(s[5])
    return msg


def image(r: ImageReading, t_ns: int, frame: str) -> Image:
    """sensor_msgs/Image, mono8, stamped at the capture time ``t_ns``."""
    h, w = r.image.shape
    return Image(header=_header(t_ns, frame), height=h, width=w, encoding="mono8",
                 is_bigendian=0, step=w, data=r.image.tobytes())


def camera_info(camera: PinholeCamera, t_ns: int, frame: str) -> CameraInfo:
    """sensor_msgs/CameraInfo of ``camera`` (its distortion model and D; K and P from its
    intrinsics, R = I)."""
    K = camera.matrix
    P = np.hstack([K, np.zeros((3, 1))])
    return CameraInfo(header=_header(t_ns, frame), height=camera.height, width=camera.width,
                      distortion_model=camera.distortion_model,
                      d=[float(v) for v in camera.distortion],
                      k=[float(v) for v in K.ravel()], r=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                      p=[float(v) for v in P.ravel()])


def static_transform(T: np.ndarray, t_ns: int, parent: str, child: str):
    """geometry_msgs/TransformStamped parent <- child of the 4x4 ``T`` (for /tf_static)."""
    from geometry_msgs.msg import TransformStamped

    msg = TransformStamped()
    msg.header = _header(t_ns, parent)
    msg.child_frame_id = child
    msg.transform.translation.x, msg.transform.translation.y, msg.transform.translation.z = (
        float(v) for v in T[:3, 3])
    msg.transform.rotation = orientation(rpy_to_quaternion(*(float(v) for v in matrix_to_rpy(T[:3, :3]))))
    return msg


def _header(t_ns: int, frame: str):
    from std_msgs.msg import Header

    return Header(stamp=stamp(t_ns), frame_id=frame)
