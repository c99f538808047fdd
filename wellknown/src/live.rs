//! The pipeline's live services as inputs of [`WellKnown`]: the subscribers a live server of these
//! messages holds (`sonar-foxglove`, `sonar-bridge --mode ros2`) and one call that empties them
//! into the converter. The conversion itself stays free of I/O; this is its only reader.

use std::fmt::Debug;

use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::service::ipc::Service as Ipc;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory;
use sonar_common::ipc::{
    self, FeatureRecord, FeaturesHeader, GridHeader, IpcError, LAYOUT_VERSION, LocalizedPose,
    Pose2D, PubSub, Reading, SlamCorrection,
};
use tracing::warn;

use crate::convert::{Output, WellKnown};

/// The pipeline's services a live server reads; the optional ones are left out with a warning
/// when their QoS has no room for another subscriber.
#[derive(Debug)]
pub struct Ports {
    readings: Subscriber<Ipc, Reading, ()>,
    grid: Option<Subscriber<Ipc, [u8], GridHeader>>,
    pose: Option<Subscriber<Ipc, Pose2D, ()>>,
    /// The corrections of the odometry: the fusion's localisation and `sonar-slam`'s.
    localized_pose: Option<Subscriber<Ipc, LocalizedPose, ()>>,
    slam_correction: Option<Subscriber<Ipc, SlamCorrection, ()>>,
    features: Option<Subscriber<Ipc, [FeatureRecord], FeaturesHeader>>,
}

fn snapshot_subscriber<T: Debug + ZeroCopySend + 'static, H: Debug + ZeroCopySend + 'static>(
    service: Result<PortFactory<Ipc, [T], H>, IpcError>,
    name: &str,
) -> Option<Subscriber<Ipc, [T], H>> {
    service
        .and_then(|s| {
            s.subscriber_builder()
                .create()
                .map_err(|e| IpcError::new("create subscriber", e))
        })
        .inspect_err(|e| warn!("not serving {name}: {e}"))
        .ok()
}

/// A subscriber of an optional service of single messages (left out with a warning).
fn optional_subscriber<T: Debug + ZeroCopySend>(
    node: &Node<Ipc>,
    open: fn(&Node<Ipc>) -> Result<PubSub<T>, IpcError>,
    name: &str,
) -> Option<Subscriber<Ipc, T, ()>> {
    open(node)
        .and_then(|s| {
            s.subscriber_builder()
                .create()
                .map_err(|e| IpcError::new("create subscriber", e))
        })
        .inspect_err(|e| warn!("not serving {name}: {e}"))
        .ok()
}

/// Each sample a subscriber holds (a failed receive is logged and ends the round).
macro_rules! for_each_sample {
    ($sub:expr, $name:expr, |$sample:ident| $body:expr) => {
        loop {
            match $sub.receive() {
                Ok(Some($sample)) => $body,
                Ok(None) => break,
                Err(e) => {
                    warn!("receiving {} failed: {e:?}", $name);
                    break;
                }
            }
        }
    };
}

impl Ports {
    /// Subscribes to the readings (required), the map, the pose, the corrections of the odometry
    /// and the features.
    pub fn open(node: &Node<Ipc>) -> Result<Self, IpcError> {
        let readings = ipc::readings_service(node)?
            .subscriber_builder()
            .create()
            .map_err(|e| IpcError::new("create readings subscriber", e))?;
        Ok(Self {
            readings,
            grid: snapshot_subscriber(ipc::grid_service(node), ipc::GRID_SERVICE),
            pose: optional_subscriber(node, ipc::pose_service, ipc::POSE_SERVICE),
            localized_pose: optional_subscriber(
                node,
                ipc::localized_pose_service,
                ipc::LOCALIZED_POSE_SERVICE,
            ),
            slam_correction: optional_subscriber(
                node,
                ipc::slam_correction_service,
                ipc::SLAM_CORRECTION_SERVICE,
            ),
            features: snapshot_subscriber(ipc::features_service(node), ipc::FEATURES_SERVICE),
        })
    }

    /// Everything that arrived since the last call, converted.
    pub fn drain(&self, converter: &mut WellKnown) -> Vec<Output> {
        let mut out = Vec::new();
        // The corrections first: the pose's transforms carry the latest with them.
        if let Some(sub) = &self.localized_pose {
            for_each_sample!(sub, ipc::LOCALIZED_POSE_SERVICE, |sample| {
                converter.localized_pose(sample.payload())
            });
        }
        if let Some(sub) = &self.slam_correction {
            for_each_sample!(sub, ipc::SLAM_CORRECTION_SERVICE, |sample| {
                converter.slam_correction(sample.payload())
            });
        }
        if let Some(sub) = &self.pose {
            for_each_sample!(sub, ipc::POSE_SERVICE, |sample| {
                out.extend(converter.pose(sample.payload()))
            });
        }
        if let Some(sub) = &self.features {
            for_each_sample!(sub, ipc::FEATURES_SERVICE, |sample| {
                out.extend(converter.features(sample.user_header(), sample.payload()))
            });
        }
        if let Some(sub) = &self.grid {
            for_each_sample!(sub, ipc::GRID_SERVICE, |sample| {
                let header = sample.user_header();
                if header.layout_version == LAYOUT_VERSION {
                    out.extend(converter.grid(header, sample.payload()));
                } else {
                    warn!(
                        layout_version = header.layout_version,
                        "map snapshot of another layout left out"
                    );
                }
            });
        }
        for_each_sample!(self.readings, ipc::READINGS_SERVICE, |sample| {
            out.extend(converter.reading(sample.payload()))
        });
        out
    }
}
