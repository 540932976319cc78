//! The protocols an agent speaks to devices: ROS 2 over rmw_zenoh and OPC UA. One value holds them, and both
//! the skills that call devices (`ros2_action`, `ros2_service`, `opcua_method`) and the chart's bound variables
//! (`crate::io`) are given it, so neither reaches into the other.

use std::sync::Arc;

use crate::opcua::OpcUa;
use crate::ros2::Ros2;
use crate::skill::Skills;

/// What the agent is connected with. `Connections::default()` speaks neither protocol: a binding to a ROS 2
/// topic or an OPC UA node then reports its device down, saying why.
#[derive(Clone, Default)]
pub struct Connections {
    ros2: Option<Arc<Ros2>>,
    opcua: Option<Arc<OpcUa>>,
}

impl Connections {
    /// ROS 2 over rmw_zenoh, on the agent's session: for `ros2_action`, `ros2_service` and topic bindings.
    pub fn with_ros2(mut self, ros2: Arc<Ros2>) -> Connections {
        self.ros2 = Some(ros2);
        self
    }

    /// OPC UA with async-opcua's client: for `opcua_method` and node bindings.
    pub fn with_opcua(mut self, opcua: Arc<OpcUa>) -> Connections {
        self.opcua = Some(opcua);
        self
    }

    pub fn ros2(&self) -> Option<&Arc<Ros2>> {
        self.ros2.as_ref()
    }

    pub fn opcua(&self) -> Option<&Arc<OpcUa>> {
        self.opcua.as_ref()
    }

    /// `skills` and the skills of each protocol connected: `ros2_action` and `ros2_service` with ROS 2,
    /// `opcua_method` with OPC UA.
    pub fn skills(&self, skills: Skills) -> Skills {
        let mut skills = skills;
        if let Some(ros2) = &self.ros2 {
            skills = skills
                .with("ros2_action", crate::ros2::skills::Ros2Action { ros2: Arc::clone(ros2) })
                .with("ros2_service", crate::ros2::skills::Ros2Service { ros2: Arc::clone(ros2) });
        }
        if let Some(opcua) = &self.opcua {
            skills = skills.with("opcua_method", crate::opcua::skills::OpcuaMethod { opcua: Arc::clone(opcua) });
        }
        skills
    }
}
