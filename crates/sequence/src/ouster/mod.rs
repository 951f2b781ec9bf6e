//! Ouster OS sensors: the metadata JSON, lidar packets, and range → XYZ as the Ouster SDK does it.

pub mod metadata;
pub mod packet;
pub mod xyz;

pub use metadata::{SensorMetadata, UdpProfile};
pub use packet::{PacketFormat, Sweep, ROS_PACKET_PAD_BYTES};
pub use xyz::XyzLut;
