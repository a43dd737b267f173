//! A media controller (`/dev/mediaN`): what the device is, its graph of entities, pads,
//! links and interfaces (MEDIA_IOC_G_TOPOLOGY, which also returns the ancillary links that tie
//! a lens to its sensor), and enabling or disabling a data link.

use super::abi::{self, zeroed};
use super::device::Device;
use std::io;

/// MEDIA_IOC_DEVICE_INFO: the driver and the model (`rkisp1`, `VIMC MDEV`, `imx-media`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Info {
    pub driver: String,
    pub model: String,
    pub bus_info: String,
}

#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Entity {
    pub id: u32,
    pub name: String,
    /// `MEDIA_ENT_F_*`.
    pub function: u32,
}

/// A device node through which an entity is reached (`/dev/videoN`, `/dev/v4l-subdevN`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Interface {
    pub id: u32,
    /// `MEDIA_INTF_T_*`.
    pub kind: u32,
    pub major: u32,
    pub minor: u32,
}

#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Pad {
    pub id: u32,
    pub entity: u32,
    pub index: u32,
    /// `MEDIA_PAD_FL_*`.
    pub flags: u32,
}

/// A link between two graph objects: pads for a data link, an interface and an entity for an
/// interface link, two entities for an ancillary link (sensor to lens).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Link {
    pub id: u32,
    pub source: u32,
    pub sink: u32,
    /// `MEDIA_LNK_FL_*`, the link type in the top four bits.
    pub flags: u32,
}

#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Topology {
    pub version: u64,
    pub entities: Vec<Entity>,
    pub interfaces: Vec<Interface>,
    pub pads: Vec<Pad>,
    pub links: Vec<Link>,
}

pub fn info(dev: &Device) -> io::Result<Info> {
    let mut i: abi::MediaDeviceInfo = zeroed();
    // SAFETY: MEDIA_IOC_DEVICE_INFO takes a media_device_info.
    unsafe { dev.ioctl::<{ abi::MEDIA_IOC_DEVICE_INFO }, _>(&mut i)? };
    Ok(Info {
        driver: abi::c_str(&i.driver),
        model: abi::c_str(&i.model),
        bus_info: abi::c_str(&i.bus_info),
    })
}

/// The whole graph. Asked twice, for the sizes and then the contents; asked again if the graph
/// changed in between (a driver still registering entities).
pub fn topology(dev: &Device) -> io::Result<Topology> {
    for _ in 0..5 {
        let mut t: abi::MediaV2Topology = zeroed();
        // SAFETY: MEDIA_IOC_G_TOPOLOGY takes a media_v2_topology; null pointers ask for counts.
        unsafe { dev.ioctl::<{ abi::MEDIA_IOC_G_TOPOLOGY }, _>(&mut t)? };
        let version = t.topology_version;
        let mut entities = vec![zeroed::<abi::MediaV2Entity>(); t.num_entities as usize];
        let mut interfaces = vec![zeroed::<abi::MediaV2Interface>(); t.num_interfaces as usize];
        let mut pads = vec![zeroed::<abi::MediaV2Pad>(); t.num_pads as usize];
        let mut links = vec![zeroed::<abi::MediaV2Link>(); t.num_links as usize];
        t.ptr_entities = entities.as_mut_ptr() as u64;
        t.ptr_interfaces = interfaces.as_mut_ptr() as u64;
        t.ptr_pads = pads.as_mut_ptr() as u64;
        t.ptr_links = links.as_mut_ptr() as u64;
        // SAFETY: each pointer addresses as many elements as its count says (the kernel writes
        // at most that many, or fails with ENOSPC when the graph grew).
        match unsafe { dev.ioctl::<{ abi::MEDIA_IOC_G_TOPOLOGY }, _>(&mut t) } {
            Ok(()) => {}
            Err(e) if e.raw_os_error() == Some(28) => continue, // ENOSPC: it grew
            Err(e) => return Err(e),
        }
        if t.topology_version != version {
            continue;
        }
        return Ok(Topology {
            version,
            entities: entities[..t.num_entities as usize]
                .iter()
                .map(|e| Entity {
                    id: e.id,
                    name: abi::c_str(&e.name),
                    function: e.function,
                })
                .collect(),
            interfaces: interfaces[..t.num_interfaces as usize]
                .iter()
                .map(|i| Interface {
                    id: i.id,
                    kind: i.intf_type,
                    major: i.devnode_major,
                    minor: i.devnode_minor,
                })
                .collect(),
            pads: pads[..t.num_pads as usize]
                .iter()
                .map(|p| Pad {
                    id: p.id,
                    entity: p.entity_id,
                    index: p.index,
                    flags: p.flags,
                })
                .collect(),
            links: links[..t.num_links as usize]
                .iter()
                .map(|l| Link {
                    id: l.id,
                    source: l.source_id,
                    sink: l.sink_id,
                    flags: l.flags,
                })
                .collect(),
        });
    }
    Err(io::Error::other(
        "the media graph kept changing while it was read",
    ))
}

/// Enables or disables the data link from `source` (entity id, pad index) to `sink`.
pub fn setup_link(
    dev: &Device,
    source: (u32, u16),
    sink: (u32, u16),
    enabled: bool,
) -> io::Result<()> {
    let mut l: abi::MediaLinkDesc = Default::default();
    l.source.entity = source.0;
    l.source.index = source.1;
    l.sink.entity = sink.0;
    l.sink.index = sink.1;
    l.flags = if enabled {
        abi::MEDIA_LNK_FL_ENABLED
    } else {
        0
    };
    // SAFETY: MEDIA_IOC_SETUP_LINK takes a media_link_desc.
    unsafe { dev.ioctl::<{ abi::MEDIA_IOC_SETUP_LINK }, _>(&mut l) }
}
