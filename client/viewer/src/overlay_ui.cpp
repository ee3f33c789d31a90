#include "overlay_ui.hpp"

#include <algorithm>
#include <cmath>

#include <imgui.h>

#include "svo/viewer/controls.hpp"

namespace svo::viewer {
namespace {

// The budget slider's range in MiB: a few slices up to more than this machine kind's memory.
constexpr int kMinBudgetMiB = 8;
constexpr int kMaxBudgetMiB = 16384;
constexpr float kMaxLodPixels = 16.0f;

ImVec4 swatch(glm::vec3 linear) {
  const auto srgb = [](float c) {
    return c <= 0.0031308f ? 12.92f * c : 1.055f * std::pow(c, 1.0f / 2.4f) - 0.055f;
  };
  return ImVec4(srgb(linear.r), srgb(linear.g), srgb(linear.b), 1.0f);
}

bool drawSettings(const OverlayStats& stats, ViewSettings& settings, int& budgetMiB) {
  bool changed = false;
  const int current = int(settings.budgetBytes >> 20);
  if (budgetMiB == 0) budgetMiB = current;
  ImGui::SliderInt("budget MiB", &budgetMiB, kMinBudgetMiB, kMaxBudgetMiB, "%d",
                   ImGuiSliderFlags_Logarithmic);
  if (budgetMiB != current) {
    ImGui::SameLine();
    if (ImGui::Button("apply")) {
      settings.budgetBytes = std::size_t(budgetMiB) << 20;
      changed = true;
    }
  }
  changed |= ImGui::SliderFloat("LOD pixels", &settings.lodPixels, 0.0f, kMaxLodPixels, "%.2f");
  changed |= ImGui::Checkbox("contours (C)", &settings.contours);
  changed |= ImGui::Checkbox("filter (B)", &settings.filter);
  int mode = int(settings.falseColor);
  const char* names[] = {nameOf(FalseColor::Shaded), nameOf(FalseColor::OctreeLevel),
                         nameOf(FalseColor::Iterations), nameOf(FalseColor::Detail)};
  if (ImGui::Combo("colors (1-4)", &mode, names, IM_ARRAYSIZE(names))) {
    settings.falseColor = FalseColor(mode);
    changed = true;
  }
  for (const LegendEntry& e : legendOf(settings.falseColor, stats.deepestLevel)) {
    ImGui::ColorButton(e.label.c_str(), swatch(e.color), ImGuiColorEditFlags_NoTooltip, ImVec2(12, 12));
    ImGui::SameLine();
    ImGui::TextUnformatted(e.label.c_str());
  }
  return changed;
}

}  // namespace

bool drawOverlay(const OverlayStats& stats, ViewSettings& settings, OverlayWidgets& widgets) {
  constexpr float kMargin = 8.0f;
  constexpr float kBackgroundAlpha = 0.75f;
  ImGui::SetNextWindowPos(ImVec2(kMargin, kMargin), ImGuiCond_Always);
  ImGui::SetNextWindowBgAlpha(kBackgroundAlpha);
  ImGui::Begin("svo view", nullptr, ImGuiWindowFlags_AlwaysAutoResize | ImGuiWindowFlags_NoMove);
  for (const std::string& line : overlayLines(stats)) ImGui::TextUnformatted(line.c_str());
  bool changed = false;
  if (!stats.opening) {
    ImGui::Separator();
    changed = drawSettings(stats, settings, widgets.budgetMiB);
  }
  if (ImGui::CollapsingHeader("keys")) ImGui::TextUnformatted(keyHelp().c_str());
  ImGui::End();
  return changed;
}

}  // namespace svo::viewer
