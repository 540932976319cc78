//! The key expressions of the two ways a ROS 2 graph is reached over Zenoh, in one place:
//! - rmw_zenoh (ROS 2 nodes on Zenoh): the data key of a topic or a service (`<domain>/<name>/<dds type>/<type
//!   hash>`), the liveliness tokens of the ROS graph
//!   (`@ros2_lv/<domain>/<zid>/<node>/<entity>/<kind>/<enclave>/<namespace>/<node name>[/<name>/<type>/<hash>/<qos>]`)
//!   and the attachment of every request and publication (sequence number, source time, source GID);
//! - zenoh-bridge-ros2dds (ROS 2 nodes on DDS, behind the bridge): the data key is the ROS name alone (`<name>`,
//!   an action's services and topics under `<name>/_action/`), and the bridge's tokens are in its Zenoh admin
//!   space, `@/<zid>/@ros2_lv/<kind>/<name>/<ROS type>[/<qos>]`, `/` written `§` in the name and the type.
//!   Neither the domain (the bridge's own setting) nor a type hash appears, and no attachment is needed.

use baton_ros2::interfaces::WireType;

const ADMIN_SPACE: &str = "@ros2_lv";
/// QoS of a service or a client as rmw_zenoh encodes it: reliable, volatile, keep last 10.
pub const SERVICE_QOS: &str = "::,10:,:,:,,";
/// QoS of a default subscription or publication (keep last 10), as `ros2 topic` makes them.
pub const TOPIC_QOS: &str = "::,10:,:,:,,";

/// QoS of a topic as the bridge encodes it (`<keyed>:<reliability>:<durability>:<history>,<depth>`, Cyclone DDS's
/// numbers, empty for the default): keyless, reliable, keep last 10 — ROS 2's default, as the bridge announces
/// a publisher made with it.
pub const BRIDGE_TOPIC_QOS: &str = ":1::0,10";
/// The chunk of a bridge's admin space that holds its tokens.
const BRIDGE_SPACE: &str = "@ros2_lv";

/// How the agent reaches the robots' ROS 2 graph.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Via {
    /// The robots run rmw_zenoh: the agent is one more node of their graph.
    RmwZenoh,
    /// The robots run DDS, and a zenoh-bridge-ros2dds routes their graph to Zenoh.
    Bridge,
}

/// A graph entity's kind, as its liveliness token spells it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    Node,
    Publisher,
    Subscription,
    Service,
    Client,
    /// An action server or client as a whole: the bridge announces actions so, rmw_zenoh by their parts.
    ActionServer,
    ActionClient,
}

impl Kind {
    fn tag(self) -> &'static str {
        match self {
            Kind::Node => "NN",
            Kind::Publisher => "MP",
            Kind::Subscription => "MS",
            Kind::Service => "SS",
            Kind::Client => "SC",
            Kind::ActionServer => "AS",
            Kind::ActionClient => "AC",
        }
    }
}

/// A ROS name in a liveliness token: `/` becomes `%`.
fn mangle(name: &str) -> String {
    name.replace('/', "%")
}

/// A topic or service name as rmw_zenoh keys it: no leading or trailing `/`.
fn strip(name: &str) -> &str {
    name.trim_matches('/')
}

/// The key a service answers on or a topic is published on.
pub fn data(via: Via, domain: u32, name: &str, wire: &WireType) -> String {
    match via {
        Via::RmwZenoh => format!("{domain}/{}/{}/{}", strip(name), wire.dds_name, wire.hash),
        Via::Bridge => strip(name).to_string(),
    }
}

/// A ROS type's name from its DDS name: `std_msgs::msg::dds_::Bool_` is `std_msgs/msg/Bool` (as rmw_zenoh
/// demangles it).
pub fn ros_type(dds_name: &str) -> String {
    hiroz_schema::type_name::ros_from_dds_strict(dds_name)
}

/// A DDS type's name from its ROS name: `std_msgs/msg/Bool` is `std_msgs::msg::dds_::Bool_`; a name that is
/// not `pkg/kind/Name` stays as it is.
pub fn dds_type(ros_name: &str) -> String {
    hiroz_schema::type_name::dds_from_canonical(ros_name).unwrap_or_else(|| ros_name.to_string())
}

/// A name or a type in one chunk of a bridge's token.
fn escape(s: &str) -> String {
    s.replace('/', "§")
}

/// The token a bridge would declare for an endpoint of `kind` on `name`, typed `ros_type`.
pub fn bridge_token(zid: &str, kind: Kind, name: &str, ros_type: &str) -> String {
    let base = format!("@/{zid}/{BRIDGE_SPACE}/{}/{}/{}", kind.tag(), escape(strip(name)), escape(ros_type));
    match kind {
        Kind::Publisher | Kind::Subscription => format!("{base}/{BRIDGE_TOPIC_QOS}"),
        _ => base,
    }
}

/// Who the agent is in the ROS graph.
#[derive(Clone, Debug)]
pub struct NodeId {
    pub domain: u32,
    pub zid: String,
    pub id: u32,
    pub namespace: String,
    pub name: String,
}

impl NodeId {
    fn prefix(&self, entity: u32, kind: Kind) -> String {
        let namespace =
            if self.namespace.is_empty() || self.namespace == "/" { "%".to_string() } else { mangle(&self.namespace) };
        format!(
            "{ADMIN_SPACE}/{}/{}/{}/{entity}/{}/%/{namespace}/{}",
            self.domain,
            self.zid,
            self.id,
            kind.tag(),
            mangle(&self.name)
        )
    }

    /// The node's own token.
    pub fn token(&self) -> String {
        self.prefix(self.id, Kind::Node)
    }

    /// An endpoint's token: a client, a subscription…
    pub fn endpoint_token(&self, entity: u32, kind: Kind, name: &str, wire: &WireType, qos: &str) -> String {
        let name = format!("/{}", strip(name));
        format!("{}/{}/{}/{}/{qos}", self.prefix(entity, kind), mangle(&name), wire.dds_name, wire.hash)
    }
}

/// The tokens of every server of `kind` (`Service`, `Publisher`…) for `name` on `domain`, whatever their type:
/// a server of another type is found too, so the agent can say why it does not answer.
pub fn servers(via: Via, domain: u32, kind: Kind, name: &str) -> String {
    match via {
        Via::RmwZenoh => {
            let name = format!("/{}", strip(name));
            format!("{ADMIN_SPACE}/{domain}/*/*/*/{}/*/*/*/{}/*/*/*", kind.tag(), mangle(&name))
        }
        Via::Bridge => format!("@/*/{BRIDGE_SPACE}/{}/{}/**", kind.tag(), escape(strip(name))),
    }
}

/// The type a server's token announces: its DDS name and hash (a bridge announces no hash: it is empty).
pub fn announced_type(via: Via, token: &str) -> Option<WireType> {
    let parts: Vec<&str> = token.split('/').collect();
    match via {
        // admin, domain, zid, node, entity, kind, enclave, namespace, node name, name, type, hash, qos
        Via::RmwZenoh => {
            (parts.len() == 13).then(|| WireType { dds_name: parts[10].to_string(), hash: parts[11].to_string() })
        }
        // @, zid, space, kind, name, type[, qos]
        Via::Bridge => (parts.len() == 6 || parts.len() == 7)
            .then(|| WireType { dds_name: dds_type(&parts[5].replace('§', "/")), hash: String::new() }),
    }
}

/// A type for messages: its DDS name and hash, or through a bridge its ROS name.
pub fn describe(via: Via, wire: &WireType) -> String {
    match via {
        Via::RmwZenoh => format!("{} ({})", wire.dds_name, wire.hash),
        Via::Bridge => ros_type(&wire.dds_name),
    }
}

/// Whether a server announcing `announced` answers a client of `wanted`. Through a bridge only the type's name
/// can be compared; `any_hash` takes a type of the same name whose hash differs (see `Node::wait_for`).
pub fn fits(via: Via, announced: &WireType, wanted: &WireType, any_hash: bool) -> bool {
    match via {
        Via::RmwZenoh => announced == wanted || (any_hash && announced.dds_name == wanted.dds_name),
        Via::Bridge => announced.dds_name == wanted.dds_name,
    }
}

/// The attachment rmw_zenoh puts on a request or a publication: sequence number and source time (little-endian
/// i64), then the source GID with its length.
pub fn attachment(sequence: i64, time_ns: i64, gid: &[u8; 16]) -> Vec<u8> {
    let mut out = Vec::with_capacity(33);
    out.extend_from_slice(&sequence.to_le_bytes());
    out.extend_from_slice(&time_ns.to_le_bytes());
    out.push(16);
    out.extend_from_slice(gid);
    out
}

/// The sequence number and GID of an attachment, if it is one.
pub fn read_attachment(bytes: &[u8]) -> Option<(i64, [u8; 16])> {
    if bytes.len() < 33 || bytes[16] != 16 {
        return None;
    }
    let sequence = i64::from_le_bytes(bytes[..8].try_into().ok()?);
    Some((sequence, bytes[17..33].try_into().ok()?))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_are_spelt_as_rmw_zenoh_spells_them() {
        let wire = WireType { dds_name: "std_srvs::srv::dds_::SetBool_".into(), hash: "RIHS01_ab".into() };
        assert_eq!(
            data(Via::RmwZenoh, 0, "/gripper/close", &wire),
            "0/gripper/close/std_srvs::srv::dds_::SetBool_/RIHS01_ab"
        );
        let node = NodeId { domain: 3, zid: "1f2e".into(), id: 0, namespace: "/".into(), name: "baton_cell1".into() };
        assert_eq!(node.token(), "@ros2_lv/3/1f2e/0/0/NN/%/%/baton_cell1");
        let client = node.endpoint_token(4, Kind::Client, "/gripper/close", &wire, SERVICE_QOS);
        assert_eq!(
            client,
            "@ros2_lv/3/1f2e/0/4/SC/%/%/baton_cell1/%gripper%close/std_srvs::srv::dds_::SetBool_/RIHS01_ab/::,10:,:,:,,"
        );
        assert_eq!(announced_type(Via::RmwZenoh, &client), Some(wire));
        assert_eq!(
            servers(Via::RmwZenoh, 3, Kind::Service, "gripper/close"),
            "@ros2_lv/3/*/*/*/SS/*/*/*/%gripper%close/*/*/*"
        );
        let att = attachment(7, 99, &[5; 16]);
        assert_eq!(att.len(), 33);
        assert_eq!(read_attachment(&att), Some((7, [5; 16])));
        assert_eq!(read_attachment(&att[..20]), None);
    }

    #[test]
    fn keys_are_spelt_as_the_bridge_spells_them() {
        let wire = WireType { dds_name: "std_srvs::srv::dds_::SetBool_".into(), hash: "RIHS01_ab".into() };
        assert_eq!(data(Via::Bridge, 7, "/gripper/close", &wire), "gripper/close");
        assert_eq!(ros_type(&wire.dds_name), "std_srvs/srv/SetBool");
        assert_eq!(dds_type("std_srvs/srv/SetBool"), wire.dds_name);
        assert_eq!(dds_type(&ros_type("geometry_msgs::msg::dds_::Twist_")), "geometry_msgs::msg::dds_::Twist_");
        let server = bridge_token("1f2e", Kind::Service, "/gripper/close", "std_srvs/srv/SetBool");
        assert_eq!(server, "@/1f2e/@ros2_lv/SS/gripper§close/std_srvs§srv§SetBool");
        let publisher = bridge_token("1f2e", Kind::Publisher, "/door", "std_msgs/msg/Bool");
        assert_eq!(publisher, "@/1f2e/@ros2_lv/MP/door/std_msgs§msg§Bool/:1::0,10");
        assert_eq!(servers(Via::Bridge, 7, Kind::Service, "/gripper/close"), "@/*/@ros2_lv/SS/gripper§close/**");
        assert_eq!(announced_type(Via::Bridge, "@/1f2e/@ros2_lv"), None, "the bridge's own token");
        let announced = announced_type(Via::Bridge, &server).unwrap();
        assert!(fits(Via::Bridge, &announced, &wire, false), "{announced:?}");
        assert!(!fits(Via::RmwZenoh, &announced, &wire, false), "no hash to compare");
        let other = announced_type(Via::Bridge, &publisher).unwrap();
        assert!(!fits(Via::Bridge, &other, &wire, false));
    }
}
