//! The pipeline's live services as inputs of [`WellKnown`]: the subscribers a live server of these
//! messages holds (`sonar-foxglove`, `sonar-bridge --mode ros2`) and one call that empties them
//! into the converter. The conversion itself stays free of I/O; this is its only reader.

use std::fmt::Debug;

use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::service::ipc::Service as Ipc;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory;
use sonar_common::ipc::{
    self, FeatureRecord, FeaturesHeader, GridHeader, IpcError, LAYOUT_VERSION, Pose2D, Reading,
};
use tracing::warn;

use crate::{Output, WellKnown};

/// The pipeline's services a live server reads; the optional ones are left out with a warning
/// when their QoS has no room for another subscriber.
#[derive(Debug)]
pub struct Ports {
    readings: Subscriber<Ipc, Reading, ()>,
    grid: Option<Subscriber<Ipc, [u8], GridHeader>>,
    pose: Option<Subscriber<Ipc, Pose2D, ()>>,
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
    /// Subscribes to the readings (required), the map, the pose and the features.
    pub fn open(node: &Node<Ipc>) -> Result<Self, IpcError> {
        let readings = ipc::readings_service(node)?
            .subscriber_builder()
            .create()
            .map_err(|e| IpcError::new("create readings subscriber", e))?;
        let pose = ipc::pose_service(node)
            .and_then(|s| {
                s.subscriber_builder()
                    .create()
                    .map_err(|e| IpcError::new("create subscriber", e))
            })
            .inspect_err(|e| warn!("not serving {}: {e}", ipc::POSE_SERVICE))
            .ok();
        Ok(Self {
            readings,
            grid: snapshot_subscriber(ipc::grid_service(node), ipc::GRID_SERVICE),
            pose,
            features: snapshot_subscriber(ipc::features_service(node), ipc::FEATURES_SERVICE),
        })
    }

    /// Everything that arrived since the last call, converted.
    pub fn drain(&self, converter: &mut WellKnown) -> Vec<Output> {
        let mut out = Vec::new();
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
