//! The iceoryx2 ends of the bridge: a [`Reader`] takes samples of a local service and frames them
//! for the link; a [`Writer`] publishes framed samples from the link into a local service. The same
//! two serve both directions (telemetry out of a robot, commands into it).

use std::fmt::Debug;

use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory;
use sonar_common::ipc::{self, FeaturesHeader, GridHeader, IpcError, PubSub};

use crate::channel::Channel;
use crate::wire::{self, Codec, Expect, FrameError, Plain, read_plain};

type Ipc = iceoryx2::service::ipc::Service;

/// Takes the next sample of a local service, framed; `Ok(None)` when there is none.
pub type Reader = Box<dyn FnMut() -> Result<Option<Vec<u8>>, IpcError>>;

/// Why a frame from the link was not published.
#[derive(Debug, thiserror::Error)]
pub enum WriteError {
    #[error(transparent)]
    Frame(#[from] FrameError),
    #[error(transparent)]
    Ipc(#[from] IpcError),
}

type WriteFn = Box<dyn FnMut(&[u8]) -> Result<(), WriteError>>;

/// Publishes one framed sample into a local service.
pub struct Writer {
    /// What the service's payload type takes: frames are checked against it.
    expect: Expect,
    write: WriteFn,
    /// Hands the latest sample (history 1) to subscribers that joined since: a publisher that
    /// idles must do this itself (`docs/ipc.md`, late joiners).
    refresh: Box<dyn FnMut()>,
}

impl std::fmt::Debug for Writer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Writer")
    }
}

impl Writer {
    /// The longest frame the service's payload type can take; a longer one is refused unread.
    pub fn max_frame_len(&self) -> usize {
        self.expect.max_frame_len()
    }

    pub fn write(&mut self, frame: &[u8]) -> Result<(), WriteError> {
        (self.write)(frame)
    }

    pub fn refresh(&mut self) {
        (self.refresh)()
    }
}

/// Cells per side of the largest grid the fusion process makes (its `MAX_CELLS_PER_SIDE`): a grid
/// frame declaring more is refused before it is decompressed.
pub const MAX_GRID_SIDE: usize = 4096;

/// How many elements a slice service's samples hold.
struct SliceLimits<H> {
    /// The publisher's first segment (it grows in power-of-two steps).
    initial: usize,
    /// How many the header says the slice has: a frame whose slice disagrees is refused.
    len_of: fn(&H) -> usize,
}

/// What a frame of `channel` must be: its payload type's layout, and for a slice the most
/// elements a sample can have.
pub fn expect(channel: Channel) -> Expect {
    match channel {
        Channel::Readings => Expect::fixed::<ipc::Reading>(),
        Channel::SweepEnds => Expect::fixed::<ipc::SweepEnd>(),
        Channel::DriverStatus => Expect::fixed::<ipc::DriverStatus>(),
        Channel::Radar => Expect::fixed::<ipc::Radar>(),
        Channel::FusionStatus => Expect::fixed::<ipc::FusionStatus>(),
        Channel::Pose => Expect::fixed::<ipc::Pose2D>(),
        Channel::LocalizedPose => Expect::fixed::<ipc::LocalizedPose>(),
        Channel::Commands => Expect::fixed::<ipc::ScanCommand>(),
        Channel::FusionCommands => Expect::fixed::<ipc::FusionCommand>(),
        Channel::Grid => Expect::slice::<GridHeader, u8>(MAX_GRID_SIDE * MAX_GRID_SIDE),
        Channel::Features => Expect::slice::<FeaturesHeader, ipc::FeatureRecord>(ipc::MAX_FEATURES),
    }
}

/// A reader of `channel`'s local service.
pub fn reader(node: &Node<Ipc>, channel: Channel) -> Result<Reader, IpcError> {
    match channel {
        Channel::Readings => fixed_reader(node, ipc::readings_service),
        Channel::SweepEnds => fixed_reader(node, ipc::sweep_ends_service),
        Channel::DriverStatus => fixed_reader(node, ipc::driver_status_service),
        Channel::Radar => fixed_reader(node, ipc::radar_service),
        Channel::FusionStatus => fixed_reader(node, ipc::fusion_status_service),
        Channel::Pose => fixed_reader(node, ipc::pose_service),
        Channel::LocalizedPose => fixed_reader(node, ipc::localized_pose_service),
        Channel::Commands => fixed_reader(node, ipc::commands_service),
        Channel::FusionCommands => fixed_reader(node, ipc::fusion_commands_service),
        Channel::Grid => slice_reader(ipc::grid_service(node)?, channel, Codec::Lz4),
        Channel::Features => slice_reader(ipc::features_service(node)?, channel, Codec::Raw),
    }
}

/// A writer into `channel`'s local service (notifying its wake-up event where it has one).
pub fn writer(node: &Node<Ipc>, channel: Channel) -> Result<Writer, IpcError> {
    let notifier = match channel.wakeup_event() {
        Some(event) => Some(ipc::wakeup_notifier(node, event)?),
        None => None,
    };
    match channel {
        Channel::Readings => fixed_writer(node, channel, ipc::readings_service, notifier),
        Channel::SweepEnds => fixed_writer(node, channel, ipc::sweep_ends_service, notifier),
        Channel::DriverStatus => fixed_writer(node, channel, ipc::driver_status_service, notifier),
        Channel::Radar => fixed_writer(node, channel, ipc::radar_service, notifier),
        Channel::FusionStatus => fixed_writer(node, channel, ipc::fusion_status_service, notifier),
        Channel::Pose => fixed_writer(node, channel, ipc::pose_service, notifier),
        Channel::LocalizedPose => {
            fixed_writer(node, channel, ipc::localized_pose_service, notifier)
        }
        Channel::Commands => fixed_writer(node, channel, ipc::commands_service, notifier),
        Channel::FusionCommands => {
            fixed_writer(node, channel, ipc::fusion_commands_service, notifier)
        }
        // 400² cells to start with; a larger grid grows the segment (power-of-two steps).
        Channel::Grid => slice_writer(
            ipc::grid_service(node)?,
            channel,
            SliceLimits {
                initial: 400 * 400,
                len_of: |h: &GridHeader| (h.width as usize).saturating_mul(h.height as usize),
            },
            notifier,
        ),
        Channel::Features => slice_writer(
            ipc::features_service(node)?,
            channel,
            SliceLimits {
                initial: ipc::MAX_FEATURES,
                len_of: |h: &FeaturesHeader| h.feature_count as usize,
            },
            notifier,
        ),
    }
}

fn fixed_reader<T: Plain + Debug>(
    node: &Node<Ipc>,
    open: fn(&Node<Ipc>) -> Result<PubSub<T>, IpcError>,
) -> Result<Reader, IpcError> {
    let service = open(node)?;
    let subscriber = service
        .subscriber_builder()
        .create()
        .map_err(|e| IpcError::new("create subscriber", e))?;
    let tag = wire::tag::<T>(None);
    Ok(Box::new(move || match subscriber.receive() {
        Ok(Some(sample)) => Ok(Some(wire::encode(
            &tag,
            wire::bytes_of(sample.payload()),
            &[],
            Codec::Raw,
        ))),
        Ok(None) => Ok(None),
        Err(e) => Err(IpcError::new("receive", e)),
    }))
}

fn slice_reader<H: Plain + Debug, E: Plain + Debug>(
    service: PortFactory<Ipc, [E], H>,
    channel: Channel,
    codec: Codec,
) -> Result<Reader, IpcError> {
    let subscriber = service
        .subscriber_builder()
        .create()
        .map_err(|e| IpcError::new(format!("create {channel} subscriber"), e))?;
    let tag = wire::tag::<H>(Some(E::tag()));
    Ok(Box::new(move || match subscriber.receive() {
        Ok(Some(sample)) => Ok(Some(wire::encode(
            &tag,
            wire::bytes_of(sample.user_header()),
            wire::slice_bytes(sample.payload()),
            codec,
        ))),
        Ok(None) => Ok(None),
        Err(e) => Err(IpcError::new(format!("receive {channel}"), e)),
    }))
}

fn notify(notifier: &Option<Notifier<Ipc>>) -> Result<(), IpcError> {
    match notifier {
        Some(n) => n.notify().map(drop).map_err(|e| IpcError::new("notify", e)),
        None => Ok(()),
    }
}

fn fixed_writer<T: Plain + Debug>(
    node: &Node<Ipc>,
    channel: Channel,
    open: fn(&Node<Ipc>) -> Result<PubSub<T>, IpcError>,
    notifier: Option<Notifier<Ipc>>,
) -> Result<Writer, IpcError> {
    let publisher = std::rc::Rc::new(
        open(node)?
            .publisher_builder()
            .create()
            .map_err(|e| IpcError::new("create publisher", e))?,
    );
    let expect = expect(channel);
    let check = expect.clone();
    let refresher = publisher.clone();
    Ok(Writer {
        expect,
        write: Box::new(move |frame| {
            let decoded = wire::decode(frame, &check)?;
            let value = match (read_plain::<T>(decoded.header), decoded.slice.is_empty()) {
                (Some(value), true) => value,
                _ => return Err(FrameError::Truncated("fixed-size payload").into()),
            };
            publisher
                .send_copy(value)
                .map_err(|e| IpcError::new("publish", e))?;
            Ok(notify(&notifier)?)
        }),
        refresh: Box::new(move || {
            let _ = refresher.update_connections();
        }),
    })
}

fn slice_writer<H: Plain + Debug + Default, E: Plain + Debug + Default>(
    service: PortFactory<Ipc, [E], H>,
    channel: Channel,
    limits: SliceLimits<H>,
    notifier: Option<Notifier<Ipc>>,
) -> Result<Writer, IpcError> {
    let publisher = std::rc::Rc::new(
        service
            .publisher_builder()
            .initial_max_slice_len(limits.initial)
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .create()
            .map_err(|e| IpcError::new(format!("create {channel} publisher"), e))?,
    );
    let expect = expect(channel);
    let check = expect.clone();
    let refresher = publisher.clone();
    let element = size_of::<E>();
    Ok(Writer {
        expect,
        write: Box::new(move |frame| {
            let decoded = wire::decode(frame, &check)?;
            let header =
                read_plain::<H>(decoded.header).ok_or(FrameError::Truncated("slice header"))?;
            let len = decoded.slice.len() / element;
            let said = (limits.len_of)(&header);
            if said != len {
                return Err(FrameError::HeaderDisagrees { said, carried: len }.into());
            }
            let mut sample = publisher
                .loan_slice_uninit(len)
                .map_err(|e| IpcError::new(format!("loan {channel} sample of {len}"), e))?;
            *sample.user_header_mut() = header;
            let slice = &decoded.slice;
            let sample = sample.write_from_fn(|i| {
                read_plain::<E>(&slice[i * element..(i + 1) * element]).unwrap_or_default()
            });
            sample
                .send()
                .map_err(|e| IpcError::new(format!("publish {channel}"), e))?;
            Ok(notify(&notifier)?)
        }),
        refresh: Box::new(move || {
            let _ = refresher.update_connections();
        }),
    })
}
#[cfg(test)]
mod frame_table {
    use super::*;

    /// `docs/bridge.md`'s frame table names every channel's type tag, header size, element size
    /// and largest slice as this build expects them: a zenoh client written from the document
    /// reads what the bridge sends.
    #[test]
    fn the_frame_table_of_docs_bridge_md_is_the_code() {
        let doc = include_str!("../../docs/bridge.md");
        for channel in Channel::ALL {
            let e = expect(channel);
            let key = format!("| `sonar/<robot>/{}` |", channel.name());
            let row = doc
                .lines()
                .find(|l| l.starts_with(&key))
                .unwrap_or_else(|| panic!("no row {key} in docs/bridge.md"));
            let cells: Vec<&str> = row.split('|').map(str::trim).collect();
            let (element, max) = if e.max_elements == 0 {
                ("–".to_owned(), "–".to_owned())
            } else {
                (e.element_len.to_string(), e.max_elements.to_string())
            };
            let want = [
                format!("`{}`", e.tag),
                e.header_len.to_string(),
                element,
                max,
            ];
            assert_eq!(&cells[2..6], &want, "{row}");
        }
    }
}
