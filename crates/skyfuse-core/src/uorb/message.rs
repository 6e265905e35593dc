//! One uORB message at a time (px4_msgs arriving over Zenoh or DDS) → a sample, by the
//! same mapping a log's rows get, so a live PX4 topic and its ULog replay agree.

use super::topics::Mapper;
use super::*;

/// The mapping of one topic, its field names resolved once.
pub struct MessageMapper {
    mapper: Mapper,
    header: Vec<String>,
    /// Names the message in errors (where a log names its file).
    name: PathBuf,
}

impl MessageMapper {
    /// `topic`: the uORB topic whose mapping applies (`sensor_combined`, ...,
    /// `vehicle_status` for the arming state); `header`: the message's field names as a
    /// log has them (`q[0]` ... for array elements); `name`: the message type, for
    /// errors.
    pub fn new(topic: &str, header: Vec<String>, name: &str) -> Result<Self, Px4LogError> {
        let name = PathBuf::from(name);
        let kind = match topic {
            "vehicle_status" => Kind::ArmingState,
            t => TOPICS
                .iter()
                .find(|(n, _, _)| *n == t)
                .map(|&(_, _, k)| k)
                .ok_or_else(|| Px4LogError::NoKnownTopics {
                    dir: name.clone(),
                    looked_for: t.to_string(),
                })?,
        };
        let mapper = Mapper::new(kind, &name, &header)?;
        Ok(Self {
            mapper,
            header,
            name,
        })
    }

    /// The sample of one message whose values are `values`, in header order: its
    /// `timestamp` and the data.
    pub fn map(&self, values: &[f64]) -> Result<(Micros, SensorData), Px4LogError> {
        let row = Row {
            file: &self.name,
            line: 1,
            header: &self.header,
            fields: Fields::One(values),
        };
        row.check_len()?;
        self.mapper.map(&row)
    }
}
