//! The pipeline's live services as inputs of [`WellKnown`]: the subscribers a live server of these
//! messages holds (`sonar-foxglove`, `sonar-bridge --mode ros2`) and one call that empties them
//! into the converter. The conversion itself stays free of I/O; this is its only reader.

use std::fmt::Debug;
use std::time::Instant;

use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::service::ipc::Service as Ipc;
use sonar_common::ipc::{
    self, FeatureRecord, FeaturesHeader, GridHeader, IpcError, LAYOUT_VERSION, LocalizedPose,
    Pose2D, Reading, SlamCorrection,
};
use sonar_common::optional_port::{OptionalPort, snapshot_subscriber, subscriber};
use tracing::warn;

use crate::convert::{Output, WellKnown};

/// The pipeline's services a live server reads; an optional one that cannot be had is left out
/// with a warning and tried again every second ([`Ports::retry_missing`]): its QoS may have no
/// room for another subscriber, or another process may be creating it at the same instant.
#[derive(Debug)]
pub struct Ports {
    readings: Subscriber<Ipc, Reading, ()>,
    grid: OptionalPort<Subscriber<Ipc, [u8], GridHeader>>,
    pose: OptionalPort<Subscriber<Ipc, Pose2D, ()>>,
    /// The corrections of the odometry: the fusion's localisation and `sonar-slam`'s.
    localized_pose: OptionalPort<Subscriber<Ipc, LocalizedPose, ()>>,
    slam_correction: OptionalPort<Subscriber<Ipc, SlamCorrection, ()>>,
    features: OptionalPort<Subscriber<Ipc, [FeatureRecord], FeaturesHeader>>,
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
            grid: OptionalPort::open(node, ipc::GRID_SERVICE, |n| {
                snapshot_subscriber(ipc::grid_service(n))
            }),
            pose: OptionalPort::open(node, ipc::POSE_SERVICE, |n| {
                subscriber(n, ipc::pose_service)
            }),
            localized_pose: OptionalPort::open(node, ipc::LOCALIZED_POSE_SERVICE, |n| {
                subscriber(n, ipc::localized_pose_service)
            }),
            slam_correction: OptionalPort::open(node, ipc::SLAM_CORRECTION_SERVICE, |n| {
                subscriber(n, ipc::slam_correction_service)
            }),
            features: OptionalPort::open(node, ipc::FEATURES_SERVICE, |n| {
                snapshot_subscriber(ipc::features_service(n))
            }),
        })
    }

    /// Tries again, once the retry period has passed, the optional subscriptions that could not
    /// be had so far.
    pub fn retry_missing(&mut self, node: &Node<Ipc>) {
        let now = Instant::now();
        self.grid.retry(node, now);
        self.pose.retry(node, now);
        self.localized_pose.retry(node, now);
        self.slam_correction.retry(node, now);
        self.features.retry(node, now);
    }

    /// Everything that arrived since the last call, converted.
    pub fn drain(&self, converter: &mut WellKnown) -> Vec<Output> {
        let mut out = Vec::new();
        // The corrections first: the pose's transforms carry the latest with them.
        if let Some(sub) = self.localized_pose.get() {
            for_each_sample!(sub, ipc::LOCALIZED_POSE_SERVICE, |sample| {
                converter.localized_pose(sample.payload())
            });
        }
        if let Some(sub) = self.slam_correction.get() {
            for_each_sample!(sub, ipc::SLAM_CORRECTION_SERVICE, |sample| {
                converter.slam_correction(sample.payload())
            });
        }
        if let Some(sub) = self.pose.get() {
            for_each_sample!(sub, ipc::POSE_SERVICE, |sample| {
                out.extend(converter.pose(sample.payload()))
            });
        }
        if let Some(sub) = self.features.get() {
            for_each_sample!(sub, ipc::FEATURES_SERVICE, |sample| {
                out.extend(converter.features(sample.user_header(), sample.payload()))
            });
        }
        if let Some(sub) = self.grid.get() {
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
