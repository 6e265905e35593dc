//! ROS 2 message definitions (`ros2msg`, the text rosbag2 writes into MCAP schemas) of the
//! types skyfuse decodes, so Foxglove and `mcap-ros2-support` can decode the recorded CDR.
//! A definition is the type's own fields, then each message it uses (`MSG: name`, after a
//! line of `=`), in the order rosbags' type store (humble) writes them; `python
//! tests/py/ros2msg.py` prints them, and tests/py/mcap_check.py checks each recorded
//! schema against it.

use crate::codec::RosType;

/// Between the parts of a definition.
const SEPARATOR: &str =
    "================================================================================\n";

/// The messages the types use, by name: their own fields.
const USED: &[(&str, &str)] = &[
    (
        "std_msgs/Header",
        r#"builtin_interfaces/Time stamp
string frame_id
"#,
    ),
    (
        "builtin_interfaces/Time",
        r#"int32 sec
uint32 nanosec
"#,
    ),
    (
        "sensor_msgs/NavSatStatus",
        r#"int8 STATUS_NO_FIX=-1
int8 STATUS_FIX=0
int8 STATUS_SBAS_FIX=1
int8 STATUS_GBAS_FIX=2
uint16 SERVICE_GPS=1
uint16 SERVICE_GLONASS=2
uint16 SERVICE_COMPASS=4
uint16 SERVICE_GALILEO=8
int8 status
uint16 service
"#,
    ),
    (
        "geometry_msgs/Quaternion",
        r#"float64 x
float64 y
float64 z
float64 w
"#,
    ),
    (
        "geometry_msgs/Vector3",
        r#"float64 x
float64 y
float64 z
"#,
    ),
    (
        "geometry_msgs/PoseWithCovariance",
        r#"geometry_msgs/Pose pose
float64[36] covariance
"#,
    ),
    (
        "geometry_msgs/Pose",
        r#"geometry_msgs/Point position
geometry_msgs/Quaternion orientation
"#,
    ),
    (
        "geometry_msgs/Point",
        r#"float64 x
float64 y
float64 z
"#,
    ),
    (
        "geometry_msgs/TwistWithCovariance",
        r#"geometry_msgs/Twist twist
float64[36] covariance
"#,
    ),
    (
        "geometry_msgs/Twist",
        r#"geometry_msgs/Vector3 linear
geometry_msgs/Vector3 angular
"#,
    ),
];

/// A type's own fields and the messages it uses, in order.
fn parts(t: RosType) -> (&'static str, &'static [&'static str]) {
    match t {
        // Written from the field tables (`definition`).
        RosType::Px4(_) => ("", &[]),
        RosType::NavSatFix => (
            r#"uint8 COVARIANCE_TYPE_UNKNOWN=0
uint8 COVARIANCE_TYPE_APPROXIMATED=1
uint8 COVARIANCE_TYPE_DIAGONAL_KNOWN=2
uint8 COVARIANCE_TYPE_KNOWN=3
std_msgs/Header header
sensor_msgs/NavSatStatus status
float64 latitude
float64 longitude
float64 altitude
float64[9] position_covariance
uint8 position_covariance_type
"#,
            &[
                "std_msgs/Header",
                "builtin_interfaces/Time",
                "sensor_msgs/NavSatStatus",
            ],
        ),
        RosType::Imu => (
            r#"std_msgs/Header header
geometry_msgs/Quaternion orientation
float64[9] orientation_covariance
geometry_msgs/Vector3 angular_velocity
float64[9] angular_velocity_covariance
geometry_msgs/Vector3 linear_acceleration
float64[9] linear_acceleration_covariance
"#,
            &[
                "std_msgs/Header",
                "builtin_interfaces/Time",
                "geometry_msgs/Quaternion",
                "geometry_msgs/Vector3",
            ],
        ),
        RosType::Range => (
            r#"uint8 ULTRASOUND=0
uint8 INFRARED=1
std_msgs/Header header
uint8 radiation_type
float32 field_of_view
float32 min_range
float32 max_range
float32 range
"#,
            &["std_msgs/Header", "builtin_interfaces/Time"],
        ),
        RosType::Odometry => (
            r#"std_msgs/Header header
string child_frame_id
geometry_msgs/PoseWithCovariance pose
geometry_msgs/TwistWithCovariance twist
"#,
            &[
                "std_msgs/Header",
                "builtin_interfaces/Time",
                "geometry_msgs/PoseWithCovariance",
                "geometry_msgs/Pose",
                "geometry_msgs/Point",
                "geometry_msgs/Quaternion",
                "geometry_msgs/TwistWithCovariance",
                "geometry_msgs/Twist",
                "geometry_msgs/Vector3",
            ],
        ),
        RosType::PoseStamped => (
            r#"std_msgs/Header header
geometry_msgs/Pose pose
"#,
            &[
                "std_msgs/Header",
                "builtin_interfaces/Time",
                "geometry_msgs/Pose",
                "geometry_msgs/Point",
                "geometry_msgs/Quaternion",
            ],
        ),
        RosType::PoseWithCovarianceStamped => (
            r#"std_msgs/Header header
geometry_msgs/PoseWithCovariance pose
"#,
            &[
                "std_msgs/Header",
                "builtin_interfaces/Time",
                "geometry_msgs/PoseWithCovariance",
                "geometry_msgs/Pose",
                "geometry_msgs/Point",
                "geometry_msgs/Quaternion",
            ],
        ),
        RosType::FlowTof => (
            r#"std_msgs/Header header
float32 distance
uint8 strength
uint8 precision
uint8 tof_status
float32 flow_vel_x
float32 flow_vel_y
uint8 flow_quality
uint8 flow_status
"#,
            &["std_msgs/Header", "builtin_interfaces/Time"],
        ),
        RosType::FluidPressure => (
            r#"std_msgs/Header header
float64 fluid_pressure
float64 variance
"#,
            &["std_msgs/Header", "builtin_interfaces/Time"],
        ),
        RosType::PointStamped => (
            r#"std_msgs/Header header
geometry_msgs/Point point
"#,
            &[
                "std_msgs/Header",
                "builtin_interfaces/Time",
                "geometry_msgs/Point",
            ],
        ),
    }
}

/// The MCAP/Foxglove schema of `t`'s CDR: its ROS 2 name and full definition.
pub fn schema(t: RosType) -> foxglove::Schema {
    foxglove::Schema::new(t.ros2_name(), "ros2msg", definition(t).into_bytes())
}

/// The full definition of `t`, dependencies included.
pub fn definition(t: RosType) -> String {
    if let RosType::Px4(m) = t {
        return crate::codec::ros::px4::definition(m.ty, m.version.unwrap_or(Px4Version::V1_16));
    }
    let (own, used) = parts(t);
    let mut text = own.to_string();
    for name in used {
        let fields = USED
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, f)| *f)
            .unwrap_or("");
        text.push_str(SEPARATOR);
        text.push_str("MSG: ");
        text.push_str(name);
        text.push('\n');
        text.push_str(fields);
    }
    text
}

use crate::codec::ros::px4::Px4Version;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_message_a_type_uses_is_in_the_table() {
        for t in RosType::ALL {
            for name in parts(t).1 {
                assert!(USED.iter().any(|(n, _)| n == name), "{name}");
            }
        }
        assert!(definition(RosType::Imu)
            .contains("MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\n"));
    }
}
